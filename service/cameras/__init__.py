"""The cameras the service knows: the SQLite store, learning one from photos, a stream's."""
