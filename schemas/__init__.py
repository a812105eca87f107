"""pydantic models: the one place where parameter names, units, defaults and ranges are declared."""
