"""Readers and writers of outside formats, one module per format."""
