"""guardrail: find, reconstruct and review guardrails in mobile-mapping data."""
