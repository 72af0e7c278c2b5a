"""Configuration: the scenario and sweep files, parsed against typed dataclasses
that check themselves."""
