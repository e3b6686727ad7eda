"""Geometry shared by every stage: frames and rotations, mesh primitives."""
