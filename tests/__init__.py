"""The test suite (a package, so the benches can use its helpers too)."""
