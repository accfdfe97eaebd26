"""Behaviour models of the eca face: pure numpy/stdlib, driven by an injectable clock."""
