"""Validation of the simulated rig over its uncertainty set (placeholder until filled in below)."""
NAME = "validation"
HELP = "the held-out closed loop over the simulated rig's uncertainty set"
DOC = "validation.md"


def add_arguments(parser) -> None:
    """No options yet."""


def run(settings) -> dict:
    raise ValueError("validation is not implemented yet")


def render(results: dict) -> dict:
    return {}
