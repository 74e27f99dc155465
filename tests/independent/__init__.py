"""Data generators written without the project's effect code, for blind tests."""
