"""Reconstruction of guardrails (Matsumoto et al. 2019, §4): one module per stage.

runs (guardrail points -> runs) -> poles (§4.1) -> units (§4.1) -> register (§4.2, ICP)
-> pipes (§4.3) | beams (§4.4) -> sweep (meshes) -> assemble (the unit copied along the run).
"""
