"""Example env_server plug-in (see examples/plugin/README.md)."""

from reach_energy.task import ReachEnergy

__all__ = ["ReachEnergy"]
