"""scenes package (filled by later issues)."""
