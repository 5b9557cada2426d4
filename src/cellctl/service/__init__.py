"""The composition root: builds the cell from its configuration (the only place drivers are imported)."""
