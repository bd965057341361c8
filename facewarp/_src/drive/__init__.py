"""Driving the face from data: tracks of markers or ARKit curves, the inverse solve, the tracker."""
