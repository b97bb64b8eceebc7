"""Kakadiaris & Metaxas.

Motion model, EKF, Jacobian, model nodes, force assignment, selection, tracker.
"""
