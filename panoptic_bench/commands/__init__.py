"""CLI sub-commands, one module per command group; each defines ``register(subparsers)``."""
