"""Fleet-scale benchmark of KyberCore (see bench/README.md)."""
