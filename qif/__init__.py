"""QIF 3.0: the results writer, the reader, schema validation and statistics documents."""
