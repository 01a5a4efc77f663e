"""sparse subpackage."""
