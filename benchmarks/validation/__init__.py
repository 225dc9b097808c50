"""Reproductions of the papers' figures and probes of their claims; tables in results/."""
