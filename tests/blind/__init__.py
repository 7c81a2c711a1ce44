"""Blind scenario generator for volucal's closed loop (see README.md). Never imports volucal."""
