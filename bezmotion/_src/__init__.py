"""Internals: linear algebra, atomic file writes, XLA options and the compilation cache. Not part of the public API."""
