"""Tests of the simulation server, scene, launch runner and replay."""
