"""Readers and writers for the files our users hold: POS.txt, Kamera.txt, the camera's raw log, EO tables."""
