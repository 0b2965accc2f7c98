"""The case file: validation, defaults, and the one place that turns a Case into domain objects."""
