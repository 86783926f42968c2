"""Every bad request gets a one-line error that names the field."""

import json

import pytest

from nurbsmotion.service.protocol import MAX_REQUEST_BYTES, ProtocolError, encode, encode_steps, parse_request
from nurbsmotion.steps import drained


def test_a_valid_request_is_decoded_with_its_fields():
    request = parse_request(b'{"cmd": "submit", "name": "a.nc", "program": "G01 X1"}')
    assert request.cmd == "submit"
    assert request.fields == {"name": "a.nc", "program": "G01 X1"}


@pytest.mark.parametrize("line, field", [
    (b'{"cmd": "submit", "name": "a.nc"', "request"),  # malformed JSON
    (b'[1, 2]', "request"),
    (b'\xff\xfe', "request"),
    (b'{"name": "a.nc"}', "'cmd'"),
    (b'{"cmd": 5}', "'cmd'"),
    (b'{"cmd": "fly"}', "'cmd'"),
    (b'{"cmd": "submit", "name": "a.nc"}', "'program'"),
    (b'{"cmd": "submit", "name": 3, "program": "x"}', "'name'"),
    (b'{"cmd": "override", "percent": "fast"}', "'percent'"),
    (b'{"cmd": "override", "percent": true}', "'percent'"),
    (b'{"cmd": "status", "verbose": 1}', "'verbose'"),
])
def test_bad_requests_name_the_field(line, field):
    with pytest.raises(ProtocolError) as info:
        parse_request(line)
    message = str(info.value)
    assert field in message and "\n" not in message


def test_oversized_requests_are_refused_before_decoding():
    with pytest.raises(ProtocolError, match="MB limit"):
        parse_request(b" " * (MAX_REQUEST_BYTES + 1))


def test_responses_are_one_line_of_json_without_nan():
    line = encode({"ok": True, "value": float("nan"), "text": "a\nb"})
    assert line.endswith(b"\n") and line.count(b"\n") == 1
    assert json.loads(line)["value"] is None


def test_non_finite_numbers_anywhere_become_null_and_finite_ones_stay_as_they_were():
    assert encode({"a": [1.5, float("inf")], "b": {"c": (float("-inf"), 2)}, "d": "x"}) == \
        b'{"a":[1.5,null],"b":{"c":[null,2]},"d":"x"}\n'
    assert encode({"a": [1.5, 0.1], "b": {"c": (3, None)}}) == b'{"a":[1.5,0.1],"b":{"c":[3,null]}}\n'


@pytest.mark.parametrize("obj", [
    {"ok": True, "axes": [{"name": "X", "mm": 1.25}], "cycles": {"late": 3, "p99": float("nan")}, "é": "ü\n"},
    {"ok": False, "error": "one line"},
    {},
])
def test_encoding_in_steps_gives_the_same_line_one_field_a_step(obj):
    steps: list[object] = []
    assert drained(encode_steps(obj), steps.append) == encode(obj)
    assert len(steps) == len(obj)


def test_encoding_in_steps_keeps_jsons_own_rules_for_keys_that_are_not_text():
    steps: list[object] = []
    assert drained(encode_steps({1: "a", None: 2}), steps.append) == encode({1: "a", None: 2}) == b'{"1":"a","null":2}\n'
    assert steps == []
