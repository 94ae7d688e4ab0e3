"""odofuse: probabilistic state estimation for wheeled mobile robots."""

__version__ = "0.1.0"
