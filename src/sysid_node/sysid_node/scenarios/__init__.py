"""Simulated scenarios for tests, benchmarks and the committed bags (pure numpy/scipy, no rclpy).

One home for every simulated structure, excitation, effect and fault:

==================  ==========================================================================
``structures``      modal structures (frequencies, damping, input gains, mode shapes; sensor
                    kind), rigid-body modes, :func:`modal_system`
``paper``           the seed paper's systems and data sets: Sec. II example, Sec. IV cobra stick
                    model and its rotor-speed dependence (Table 2)
``timevarying``     piecewise-constant (switching, LPV, drifting) simulation in blocks
``closedloop``      plant + known discrete controller + reference
``excitations``     white, coloured, multisine (Schroeder), sweep, sine dwell, ambient
``noise``           measurement noise
``effects``         the seven hidden effects of ``validate``, parameterised
``faults``          sensor / data faults on (stamps, values, names)
``truth``           true modes over time (``TrueMode``), the bags' truth format
``draw``            seeded random modal records (``draw_modal_scenario``, ``drifting_mode``)
``draw_effects``    seeded random hidden-effect records (``draw_hidden_effect``, ``draw_clean``)
``bags``            the scenarios of the committed bags (``bags/``, ``bags/hidden/``)
==================  ==========================================================================

Every random function takes an explicit ``numpy.random.Generator`` (or a seed).
"""

from .draw import DriftingScenario, ModalScenario, draw_modal_scenario, drifting_mode
from .draw_effects import EffectScenario, draw_clean, draw_hidden_effect
from .effects import EFFECTS
from .structures import ModalStructure, modal_system
from .truth import TrueMode

__all__ = [
    "EFFECTS",
    "DriftingScenario",
    "EffectScenario",
    "ModalScenario",
    "ModalStructure",
    "TrueMode",
    "draw_clean",
    "draw_hidden_effect",
    "draw_modal_scenario",
    "drifting_mode",
    "modal_system",
]
