"""OpenIGTLink live: the fused tip, shaft and trocar as TRANSFORM messages for 3D Slicer."""
