"""dsnet subpackage."""
