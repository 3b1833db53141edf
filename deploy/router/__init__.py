"""`hubctl router`: a Zenoh router of the site (DESIGN.md §14), configured from line.toml."""
