"""What the daemon keeps on disk: atomic file writes, the state database (run history, ingest
journal, controller state) and the inbox of light bundles with their manifests."""
