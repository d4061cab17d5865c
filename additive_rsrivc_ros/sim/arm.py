"""A simulated multi-joint arm with known truth: every joint a rigid body plus one flexible mode, under the PD
controller of the ``rigid_body`` scenario, at 1 kHz or any other rate (the controller is re-derived per rate).

Each joint has its own plant (:data:`ARM_JOINTS`: flexible mode 6-16 Hz, its own inertia and damping) and its own
setpoint (square wave with its own period) and noise; an optional fault drops one joint's flexible-mode frequency at
``fault_time_s``. The joints are independent loops sampled together, as a robot controller publishes them in one
``JointState`` per sample. :func:`arm_params` gives the params of ``rsrivc_joints`` for them (config/joints/arm.yaml
is that file for the seven joints at 1 kHz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.controller import DiscreteController
from .simulate import ModalChange, PlantMode, simulate_modes, square_wave, white_noise

# (flexible-mode frequency Hz, its damping ratio, rigid-body gain 1/inertia) per joint
ARM_JOINTS: tuple[tuple[float, float, float], ...] = (
    (6.0, 0.03, 1.0), (7.5, 0.025, 1.2), (9.0, 0.02, 0.9), (10.5, 0.02, 1.1), (12.0, 0.015, 1.0),
    (14.0, 0.015, 0.8), (16.0, 0.01, 1.0))
FLEX_GAIN_AT_8HZ = 0.004          # flexible-mode DC gain at 8 Hz (rigid_body scenario); scaled as 1/f^2
NOISE_STD = 2e-5
KP, KD, LOWPASS_HZ = 12.484, math.pi, 100.0   # the rigid_body scenario's PD with its first-order low-pass


def pd_controller(rate_hz: float) -> DiscreteController:
    """``C_d = (kp + kd (1 - q^-1)/h) (1 - a)/(1 - a q^-1)``, ``a = exp(-2 pi 100 h)`` (config/rigid_body.yaml)."""
    h = 1.0 / rate_hz
    a = math.exp(-2.0 * math.pi * LOWPASS_HZ * h)
    num = np.array([KP + KD / h, -KD / h]) * (1.0 - a)
    return DiscreteController(numerator=tuple(float(x) for x in num), denominator=(1.0, -a))


def joint_modes(k: int) -> tuple[PlantMode, PlantMode]:
    """Plant of joint ``k`` (0-based; beyond the table the frequencies continue upwards)."""
    f, zeta, b = ARM_JOINTS[k % len(ARM_JOINTS)]
    f *= 1.0 + 0.1 * (k // len(ARM_JOINTS))
    return PlantMode(0.0, 0.0, b, integrators=2), PlantMode(f, zeta, FLEX_GAIN_AT_8HZ * (8.0 / f) ** 2)


@dataclass
class ArmJoint:
    """One joint's simulated samples and truth (``truth``: (2, N, 3) f_hz, zeta, gain per mode and sample)."""

    name: str
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    truth: np.ndarray
    modes: tuple[PlantMode, PlantMode]
    changes: list[ModalChange] = field(default_factory=list)


def simulate_arm(names: list[str], rate_hz: float, duration_s: float, seed: int = 0, *,
                 fault_joint: str | None = None, fault_time_s: float = 0.0, fault_size: float = 0.08) -> list[ArmJoint]:
    """Every joint of ``names`` simulated in closed loop with 1 sample input delay; ``fault_joint``'s flexible-mode
    frequency drops by ``fault_size`` (relative, a step) at ``fault_time_s``."""
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    ctrl = pd_controller(rate_hz)
    out = []
    for k, name in enumerate(names):
        rng = np.random.default_rng([seed, k, 7])
        modes = joint_modes(k)
        r = square_wave(t, 0.5 / (1.0 + 0.15 * k), 0.1)
        changes = [ModalChange(1, "frequency", -fault_size, fault_time_s)] if name == fault_joint else []
        sim = simulate_modes(modes, rate_hz, changes=changes, r=r, controller=ctrl, input_delay=1,
                             noise=white_noise(n, NOISE_STD, rng), rng=rng)
        assert sim.r is not None   # closed loop: the simulation keeps the reference
        out.append(ArmJoint(name, sim.r, sim.u, sim.y, sim.modal, modes, changes))
    return out


def joint_section(k: int) -> dict[str, Any]:
    """The ``modes`` section of joint ``k``'s params (guesses = the plant)."""
    rigid, flex = joint_modes(k)
    return {"natural_frequency_hz": [0.0, flex.natural_frequency_hz], "damping_ratio": [0.0, flex.damping_ratio],
            "gain": [rigid.gain, flex.gain], "integrators": [2, 0], "memory_s": [20.0, 5.0]}


def arm_params(names: list[str], rate_hz: float) -> dict[str, Any]:
    """``ros__parameters`` of ``rsrivc_joints`` for the simulated arm (shared plant settings, per-joint modes)."""
    ctrl = pd_controller(rate_hz)
    params: dict[str, Any] = {
        "joints": list(names), "loop_rate_hz": float(rate_hz), "closed_loop": True,
        "controller": {"numerator": [float(x) for x in ctrl.num], "denominator": [float(x) for x in ctrl.den]},
        "input_delay_samples": 1, "init_duration_s": 10.0, "publish_rate_hz": 10.0}
    for k, name in enumerate(names):
        params[name] = {"modes": joint_section(k)}
    return params
