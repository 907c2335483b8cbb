"""Restraint: the restrained hold (ISO 10579), the free-state scan read at its clamps and
moved by the part's elastic response, and where each locator's face went."""
