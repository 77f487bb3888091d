"""The framework every node stands on: base node, drivers, parameters, registry, errors."""
