"""Production: orders, the order book, where orders come from, and throughput (DESIGN.md §12)."""
