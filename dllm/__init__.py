"""dllm package (filled by later issues)."""
