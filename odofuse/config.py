"""Run configuration (YAML, see shared spec section 2)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class RunConfig:
    """A validated run configuration.

    ``robot``/``motion``/``initial`` are the validated YAML blocks (plain dicts, SI units);
    ``sensors`` maps a stream name to its sensor block; ``options`` maps an estimator name to its
    own option block (e.g. ``options: {ekf: {late_window: 0.5}}``); ``source`` is the config
    file path, for error messages.
    """

    log: str
    robot: dict
    motion: dict = field(default_factory=dict)
    estimator: str = "dead_reckoning"
    initial: dict = field(default_factory=dict)
    sensors: dict = field(default_factory=dict)
    output: str | None = None
    options: dict = field(default_factory=dict)
    source: str = "<config>"

    def option_block(self, estimator: str | None = None) -> dict:
        """The option block of ``estimator`` (default: this run's estimator), ``{}`` if absent."""
        return dict(self.options.get(estimator or self.estimator, {}) or {})
