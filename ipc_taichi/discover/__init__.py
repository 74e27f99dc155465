"""Model-discrepancy workflow: where simulation and measured data disagree,
which detector effect is missing, and how much of the gap it closes.

See ``docs/discover.md``. Main entry points: :func:`discover` (a lab FITS
file in, a report out), :class:`DetectorModel` (the ordered chain of effects)
and :func:`simulate_lab` (the data generator); ramps (3-D MEASURED):
:func:`read_ramps` and :func:`discover_ramps`.
"""

from .effects import EFFECT_NAMES, EFFECTS
from .labdata import LabData, LabPair, make_scene, read_lab, simulate_lab, write_lab
from .model import CHAIN_ORDER, DetectorModel
from .ramp_search import discover_ramps
from .ramps import read_ramps
from .search import Discovery, discover

__all__ = ["discover", "discover_ramps", "read_ramps", "Discovery", "DetectorModel",
           "CHAIN_ORDER", "EFFECTS", "EFFECT_NAMES", "LabData", "LabPair", "read_lab",
           "write_lab", "make_scene", "simulate_lab"]
