"""Bridges to other tools' plugin systems."""
