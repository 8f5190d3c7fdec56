"""What every stage uses: errors users see (InputError, exit code 2), read-only arrays, atomic file
writes and TOML reading. Takes nothing from the pipeline and imports nothing of jiggle's."""
