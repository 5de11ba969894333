"""The fill stage: tracks where a view lost a person the other views see (gaps: where; look: BlazePose
at the projected skeleton; stage: the workspace runner, fill/)."""

__all__ = ["stage"]
