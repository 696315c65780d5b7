"""matforge-ashikhmin: a matforge job kind from another package (see README.md)."""
