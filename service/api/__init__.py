"""The HTTP layer: routes, their dependencies, the answers' schemas, errors and limits."""
