"""What the API's bodies share: the strict request body, digits-only path and query
integers, coach ids and the error message."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator


def _storable(text: str, where: str) -> None:
    """ValueError unless ``text`` can be stored: no NUL character (PostgreSQL refuses it in
    text) and no lone surrogate (not UTF-8)."""
    if "\x00" in text:
        raise ValueError(f"{where}: must not contain a NUL character")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError(f"{where}: must be valid Unicode (a lone surrogate is not)") from None


class Strict(BaseModel):
    """A request body: unknown fields are an error (a typo must not be silently ignored), and no
    string in it — a field's, or an item of a field's list — may hold a NUL character or a lone
    surrogate (422 on SQLite and PostgreSQL alike; a nested body checks its own). Its booleans
    are :class:`~pydantic.StrictBool` (``"yes"`` or ``0`` is no boolean)."""

    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="before")
    @classmethod
    def _storable_text(cls, data):
        if isinstance(data, dict):
            for key, value in data.items():
                if isinstance(value, str):
                    _storable(value, key)
                elif isinstance(value, list):
                    for item in value:
                        if isinstance(item, str):
                            _storable(item, key)
        return data


def _whole(value):
    """A path or query value as a whole number: digits only (``1.0``, ``+1``, ``1_0`` are not)."""
    if isinstance(value, str) and not (value.isascii() and value.isdigit()):
        raise ValueError("must be a whole number, digits only")
    return value


#: An integer path or query parameter is written in digits only (``/tokens/1.0`` is no token id):
#: ``Annotated[int, Path(ge=1), DIGITS_ONLY]`` — after the ``Path`` or ``Query``, whose bounds
#: then stay in the schema as its minimum and maximum.
DIGITS_ONLY = BeforeValidator(_whole)


CoachIds = list[Annotated[str, Field(min_length=1, max_length=32, pattern=r"^[A-Za-z0-9_.-]+$")]]


class Message(BaseModel):
    detail: str
