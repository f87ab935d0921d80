"""Cross-package command-line behaviour (errors, exit codes)."""
