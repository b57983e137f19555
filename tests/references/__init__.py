"""Scalar reference versions of batched code, for the tests that compare the two."""
