"""Guardrail extraction (Matsumoto et al. 2019, §3): road removal, lattice segments, crops, CNN, label correction."""
