"""The language memory: typed entries, the rule-based writer, the bounded bank, the encoder."""
