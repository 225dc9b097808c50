"""Actuation routines and the controller node."""
