"""The project's own folders: drive, run folder, label store."""
