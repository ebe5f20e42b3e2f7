"""`tiplog export`: a recording's fused estimate for other tools (LeRobot, 3D Slicer, CSV)."""
