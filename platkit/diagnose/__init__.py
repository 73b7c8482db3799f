"""Diagnosis: find where calibrated residuals are structured, name the physics the model left out
from the effect library, model it, and accept it only on held-out proof.

Public API: :func:`diagnose` (search.py), :class:`Options`, :class:`Diagnosis`, :class:`Finding`,
:func:`locate` (locate.py), :func:`effect_library`, :func:`term_from_dict`, :func:`with_history`
(effects.py), :func:`write_outputs` (report.py).
"""
from platkit.diagnose.locate import Location, locate, located
from platkit.diagnose.search import Diagnosis, Finding, Options, diagnose
from platkit.effects import Effect, effect_library, term_from_dict, with_history

__all__ = ["Effect", "effect_library", "term_from_dict", "with_history", "Location", "locate", "located",
           "Diagnosis", "Finding", "Options", "diagnose"]
