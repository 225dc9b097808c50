"""The Reissner shell model of paper 000: geometry, parameters and stepping, kernels."""
