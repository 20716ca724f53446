"""HighD-format recordings: schema, reader with validation, generator, conversion to ITHA data, replay."""
