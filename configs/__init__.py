"""YAML configuration presets."""
