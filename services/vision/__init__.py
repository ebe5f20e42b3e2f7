"""Vision service: shaft silhouette, consistency gate and tangent-plane geometry from each camera frame."""
