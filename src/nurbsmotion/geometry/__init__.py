"""Curves: NURBS evaluation, derivatives, curvature, arc length; lines and arcs as NURBS."""

from nurbsmotion.geometry.nurbs import CurveError, NurbsCurve, clamped_uniform_knots

__all__ = ["CurveError", "NurbsCurve", "clamped_uniform_knots"]
