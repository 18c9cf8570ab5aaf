"""One recording file: container I/O, decoding, contract checks, the typed recording, salvage."""
