"""A line of stations over Zenoh routers: `hubctl line controller|up` (DESIGN.md §14, docs/line.md)."""
