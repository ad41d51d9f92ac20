"""Files: atomic writes and strict JSON (`files`), motion problems as TOML files
(`problemfile`)."""
