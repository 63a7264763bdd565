"""The plants ``cosim demo`` runs on (``--plant``), and their names of the one-FMU servo's signals."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import InvalidSettingError
from .loop.validation import disturbance_step, setpoint_step
from .plant.build import build_fmu, build_ssp
from .study.paper import STATES

__all__ = ["DEMO_PLANTS", "DEMO_SCENARIOS", "DemoPlant", "demo_plant"]

#: The demo's closed-loop scenarios: a 0.01 rad load-angle step, then a 500 N m load-torque step.
DEMO_SCENARIOS = (setpoint_step(0.01, at=0.05, duration=2.0), disturbance_step(500.0, at=0.3, duration=2.0))

#: The plants the demo runs on (``cosim demo --plant``).
DEMO_PLANTS = ("bundled", "split")


@dataclass(frozen=True)
class DemoPlant:
    """The plant of the demo: its file, what the report calls it, and its names of the one-FMU servo's signals and
    parameters (``{"Tm": "motor.Tm", "Fc": "motor.Fc", ...}`` for the split servo; none for the bundled one)."""

    path: Path
    label: str
    names: Mapping[str, str] = field(default_factory=dict)

    def n(self, name: str) -> str:
        """This plant's name of the one-FMU servo's `name`."""
        return self.names.get(name, name)

    @property
    def states(self) -> tuple[str, ...]:
        return tuple(self.n(s) for s in STATES)

    def scenarios(self) -> tuple[Any, ...]:
        """:data:`DEMO_SCENARIOS`, the load step on this plant's load-torque input."""
        return (DEMO_SCENARIOS[0], disturbance_step(500.0, input=self.n("TL"), at=0.3, duration=2.0))


def demo_plant(kind: str = "bundled") -> DemoPlant:
    """The demo's plant: ``"bundled"``, the two-mass servo FMU; ``"split"``, the same servo as a motor FMU and a
    shaft-and-load FMU wired by an SSP file (fmus/two_mass_servo_split), run by cosim's system master."""
    if kind == "bundled":
        return DemoPlant(build_fmu(), "the bundled two-mass servo")
    if kind == "split":
        names = {n: f"motor.{n}" for n in ("Tm", "theta_m", "omega_m", "Fc")}
        names.update({n: f"load.{n}" for n in ("TL", "theta_L", "omega_L")})
        return DemoPlant(build_ssp(), "the bundled servo split into a motor FMU and a shaft-and-load FMU (an SSP "
                         "system run by cosim's master)", names)
    raise InvalidSettingError(f"plant {kind!r}; choose {' or '.join(DEMO_PLANTS)}")
