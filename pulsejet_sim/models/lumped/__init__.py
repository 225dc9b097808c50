"""The lumped model of paper 001: parameters (model), kernels (kernels), N robots (batch)."""
