"""Kakadiaris & Metaxas: motion model, EKF, Jacobian, model nodes, force assignment, selection, tracker."""
