"""Importers: data recorded elsewhere (LAS/LAZ deliveries, KITTI scans) as drive folders."""
