"""The store's records against the API schemas they feed: each typed dict of
:mod:`trainclimate.service.store.records` has the keys of its schema's fields, but for the fields
the API adds itself and the keys it converts, each named here with where it happens, so the two
cannot drift apart unnoticed."""

from __future__ import annotations

import typing
from dataclasses import dataclass, field

import pytest
from pydantic import BaseModel

from trainclimate.service.api.schemas import coaches, health, telemetry
from trainclimate.service.store import records


@dataclass(frozen=True)
class Pair:
    """A record and the schema the API validates it into."""

    record: type
    schema: type[BaseModel]
    #: The schema's fields the record has not: field → what adds it.
    added: dict[str, str] = field(default_factory=dict)
    #: The record's keys the schema holds as one field: key → field (and what converts them).
    folded: dict[str, str] = field(default_factory=dict)


DECKS = {"t_room_up_c": "t_room_c", "t_room_mid_c": "t_room_c", "t_room_low_c": "t_room_c"}
PAIRS = [
    # store.telemetry.to_wire and from_wire convert the decks (a list on the wire)
    Pair(records.TelemetryRecord, telemetry.TelemetryRow, folded=DECKS),
    Pair(records.ComfortNow, coaches.ComfortNow),
    Pair(records.CoachView, coaches.CoachOut),
    Pair(records.SetpointView, telemetry.SetpointOut),
    Pair(records.NoSetpoint, telemetry.SetpointOut),
    Pair(records.TimeSeries, coaches.TimeSeries),
    Pair(records.SetpointHistory, coaches.SetpointHistory),
    Pair(
        records.Replica,
        health.ReplicaOut,
        added={"this": "GET /replicas marks the replica answering (api.health.replicas)"},
    ),
]


def keys(record: type) -> set[str]:
    """A typed dict's keys, required or not."""
    return set(record.__required_keys__ | record.__optional_keys__)


def test_every_record_has_its_schema():
    typed = {v for v in vars(records).values() if typing.is_typeddict(v)}
    assert typed == {p.record for p in PAIRS}


@pytest.mark.parametrize("pair", PAIRS, ids=lambda p: p.record.__name__)
def test_a_records_keys_are_its_schemas_fields(pair):
    fields = set(pair.schema.model_fields)
    assert set(pair.added) <= fields - keys(pair.record), "an added field is not the API's own"
    assert set(pair.folded) <= keys(pair.record), "a folded key is not the record's"
    assert {pair.folded.get(k, k) for k in keys(pair.record)} == fields - set(pair.added)
