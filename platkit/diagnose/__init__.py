"""Diagnosis: find where calibrated residuals are structured, name the physics the model left out
from the effect library, model it, and accept it only on held-out proof.

Public API: :func:`diagnose` (search.py), :class:`Options`, :class:`Diagnosis`, :class:`Finding`,
:func:`locate` (locate.py), :func:`with_history` (effects.py), :func:`effect_library`,
:func:`term_from_dict` (plugins.py), :func:`write_outputs` (report.py).
"""
from platkit.diagnose.fitting import Diagnosis, Finding, Options
from platkit.diagnose.locate import Location, locate, located
from platkit.diagnose.search import diagnose
from platkit.effects import Effect, with_history
from platkit.plugins import effect_library, term_from_dict

__all__ = ["Effect", "effect_library", "term_from_dict", "with_history", "Location", "locate", "located",
           "Diagnosis", "Finding", "Options", "diagnose"]
