"""The mobile-mapping simulator: scene specs to meshes with truth, the scanner and the cameras."""
