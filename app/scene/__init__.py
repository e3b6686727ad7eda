"""The 3D scene of the review app (viser): a window of the drive, picking, colours, the tuning panel."""
