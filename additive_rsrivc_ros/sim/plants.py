"""The papers' reference plants and controllers, written out once ([RA-SRIVC] §5, §6; [A-SRIVC] §5.2, §6).

Parameter vectors are in the [RA-SRIVC] eq. 7 order ``[a1, a2, b0]`` of ``b0 / (a2 p^2 + a1 p + 1)`` unless stated;
modal forms are :class:`~additive_rsrivc_ros.sim.simulate.PlantMode` (natural frequency Hz, damping, gain).
Used by the scenarios, ``rsrivc_bench``, ``rsrivc_evaluate``, the validation scripts and the tests.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.controller import DiscreteController
from ..core.model import SubmodelStructure, second_order_modal
from .simulate import PlantMode

#: [RA-SRIVC] §5 / [A-SRIVC] §5.2 discrete PID ``(0.02329 q^2 - 0.02058 q + 0.00454)/(q^2 - q)`` (DESIGN.md erratum 1)
PAPER_PID_NUM = (0.02329, -0.02058, 0.00454)
PAPER_PID_DEN = (1.0, -1.0, 0.0)
PAPER_PID = DiscreteController(PAPER_PID_NUM, PAPER_PID_DEN)

#: [RA-SRIVC] §5: a2 = [0.25, 0.04, 0.0025], a1 = [0.25, 0.01, 0.01], b0 = [3, 0.5, 1], 20 Hz
PAPER_THETAS = [np.array([0.25, 0.25, 3.0]), np.array([0.01, 0.04, 0.5]), np.array([0.01, 0.0025, 1.0])]
PAPER_MODES = (PlantMode(1.0 / (2 * math.pi * 0.5), 0.25, 3.0), PlantMode(1.0 / (2 * math.pi * 0.2), 0.025, 0.5),
               PlantMode(1.0 / (2 * math.pi * 0.05), 0.1, 1.0))

#: [A-SRIVC] §5.2 closed-loop example (eq. 46): ``3/(0.25p^2+0.25p+1) + 1/(0.025p^2+0.01p+1)``, h = 0.05 s, PAPER_PID
CL52_THETAS = [np.array([0.25, 0.25, 3.0]), np.array([0.01, 0.025, 1.0])]

#: [BCD-SRIVC] case study 1 (open loop, h = 0.005 s): ``3/(0.25p^2+0.25p+1) + 1/(0.0025p^2+0.01p+1)``
BCD_THETAS = [np.array([0.25, 0.25, 3.0]), np.array([0.01, 0.0025, 1.0])]

#: [A-SRIVC] §6 converged beam estimates, written here as ``[a2, a1, b0]``: f ~ [3.25, 33.0, 171.7, 183.2] Hz
_BEAM_A2_A1_B0 = ((0.0024, 0.023, 11.81), (2.33e-5, 1.65e-4, 0.159), (8.59e-7, 1.03e-5, 3.19e-4),
                  (7.55e-7, 3.55e-6, 1.27e-4))
#: the beam truth in [RA-SRIVC] eq. 7 order ([RA-SRIVC] §6 / [A-SRIVC] §6; 4096 Hz, 4-sample input delay, K = 2 fitted)
BEAM_THETAS = [np.array([a1, a2, b0]) for a2, a1, b0 in _BEAM_A2_A1_B0]


def _beam_mode(a2: float, a1: float, b0: float) -> PlantMode:
    """A mode from the [A-SRIVC] §6 estimates ``[a2, a1, b0]`` (a2 = 0.0024 is 3.25 Hz)."""
    f_hz, zeta = second_order_modal(a1, a2)
    return PlantMode(float(f_hz), float(zeta), b0)


#: the beam's four modes (modes 3-4 are not estimated with K = 2)
BEAM_MODES = tuple(_beam_mode(*m) for m in _BEAM_A2_A1_B0)
BEAM_NOISE_STD = 3.0e-4  # ~3 % of the std of mode 2's output contribution (0.011 with the 0.1 square wave)


def beam_controller(rate_hz: float = 4096.0) -> DiscreteController:
    """A stabilizing PID for the beam truth of :mod:`.sim.plants` (4 modes, delay 4): modulus margin 0.52 (0.60 with the
    second mode's stiffness -30 %), slowest closed-loop pole 0.99948.

    ``C = kp + ki h/(1 - q^-1) + kd (1 - q^-1)/(tf + h - tf q^-1)`` (backward Euler, derivative filtered at
    50 Hz), kp = 0.3, ki = 3, kd = 0.01.
    """
    h = 1.0 / rate_hz
    kp, ki, kd, tf = 0.3, 3.0, 0.01, 1.0 / (2 * np.pi * 50.0)
    a = tf + h
    num_pd = np.array([kp * a + kd, -kp * tf - kd]) / a
    den_pd = np.array([1.0, -tf / a])
    num = np.convolve(num_pd, [1.0, -1.0]) + np.convolve([ki * h, 0.0], den_pd)
    den = np.convolve(den_pd, [1.0, -1.0])
    return DiscreteController(tuple(num), tuple(den))


#: [UNS-SRIVC] §7.1 / eq. 31 unstable plant ``(-0.5 p + 1)/(p^2 + 2 xi wn p + wn^2)``, wn^2 = 2, xi = -0.05, h = 0.1 s,
#: anti-monic ``[a1, a2, b0, b1]`` ([UNS-SRIVC] Table 1: a1 = -0.0707, a2 = 0.5, b0 = 0.5, b1 = -0.25)
UNS_STRUCTURE = SubmodelStructure(n=2, m=1)
_WN2, _XI = 2.0, -0.05
UNS_THETA = np.array([2 * _XI * np.sqrt(_WN2) / _WN2, 1 / _WN2, 1 / _WN2, -0.5 / _WN2])
#: its discrete PID in q^-1 over (1 - q^-1) ([UNS-SRIVC] §7.1)
UNS_PID_NUM = (0.0272 + 2.54e-5 + 7.29, -(0.0272 + 2 * 7.29), 7.29)
UNS_PID_DEN = (1.0, -1.0)
#: [UNS-SRIVC] Table 1 standard deviations of ``[a1, a2, b0, b1]`` (srivc-uns, clsrivc-uns)
UNS_TABLE1_SD = {"srivc-uns": np.array([1.49e-3, 1.00e-3, 3.82e-3, 1.17e-3]),
                 "clsrivc-uns": np.array([1.53e-3, 1.12e-3, 3.96e-3, 2.10e-3])}

#: [UNS-SRIVC] §7.4 integrator plant ``(p - 2)/(p (p + 1))``: solution 2 ``B/(p A)``, A = 1 + p, B = -2 + p ...
INT_STRUCTURE = SubmodelStructure(n=1, m=1, integrators=1)
INT_THETA = np.array([1.0, -2.0, 1.0])
#: ... and solution 1 (monic ``A = p^2 + a1 p + a0``, a0 = 0): layout ``[a0, a1, b0, b1]``
INT_MONIC_THETA = np.array([0.0, 1.0, -2.0, 1.0])
#: its closed-loop controller ``C = -0.249 - 2.07 (1 - q^-1)``
INT_CONTROLLER_NUM, INT_CONTROLLER_DEN = (-0.249 - 2.07, 2.07), (1.0,)
