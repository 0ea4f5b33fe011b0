"""Makes the repository root importable in tests, so they can reuse bench/ and samples/ scripts."""
