"""classifiers package (filled by later issues)."""
