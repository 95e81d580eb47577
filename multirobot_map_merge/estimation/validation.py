"""Checks the stage settings share: each raises ValueError naming the first bad setting."""


def must_be_positive(settings, *names: str) -> None:
    """Raise ValueError naming the first of these settings that is not positive."""
    for name in names:
        if not getattr(settings, name) > 0:
            raise ValueError(f'{name} must be positive, not {getattr(settings, name)}')


def must_not_be_negative(settings, *names: str) -> None:
    """Raise ValueError naming the first of these settings that is negative (or NaN)."""
    for name in names:
        if not getattr(settings, name) >= 0:
            raise ValueError(f'{name} must not be negative, not {getattr(settings, name)}')
