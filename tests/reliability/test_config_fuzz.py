"""Thousands of mutated machine configurations: each is accepted or rejected with an
InputError whose every line starts with the source name and stays one readable line;
never another exception, never a runaway message (YAML aliases can expand exponentially).

Character- and line-level mutations come from the program fuzzer (tests/program/test_fuzz);
here they are added to by value-level ones that know YAML: wrong types, tags, aliases,
special floats, deep nesting.
"""

from __future__ import annotations

import random
import re
from pathlib import Path

import pytest

from nurbsmotion.config import MachineConfig, parse_config
from nurbsmotion.errors import InputError
from tests.program.test_fuzz import GARBAGE, mutate

CONFIG_DIR = Path(__file__).resolve().parents[2] / "config"
SOURCE = "fuzz.yaml"
CASES = 1500  # per kind of mutation: 3000 configurations
MAX_LINE = 2000  # one readable line (an unknown key is echoed in full, twice)
FULL_TEMPLATE = """cycle_period_ms: 2
simulate: false
bus: {interface: virtual, channel: fuzz, bitrate: 500000}
interpolation: {algorithm: wang, feed_mm_min: 3000, rapid_feed_mm_min: 6000, chord_error_mm: 0.01,
                max_accel_mm_s2: 1000, max_jerk_mm_s3: null, acc_time_s: 0.1, junction_deviation_mm: 0.02}
axes:
  - name: X
    node_id: 1
    mode: ip
    counts_per_mm: 1000
    invert: true
    offset_counts: -5
    soft_limits_mm: [-100, 100]
    max_velocity_mm_s: 200
    max_accel_mm_s2: 2000
    following_error_window_mm: 2.0
    following_error_timeout_ms: 40
    identity: {vendor_id: 0x1234, product_code: 66}
    quick_stop_decel: 2000000
    sdo:
      - {index: 0x60C4, subindex: 2, value: 1, type: uint32}
      - {index: 0x1007, value: 1500}
  - {name: Y, node_id: 2, mode: csp, eds: drives/servo.eds}
master: {node_id: 100}
monitoring: {heartbeat_producer_ms: 100, heartbeat_consumer_ms: 300, max_bus_load: 0.8, master_heartbeat_ms: 50,
             master_heartbeat_consumer_multiple: 4}
control: {socket: /tmp/fuzz.sock, group: null}
data_dir: var/fuzz
"""
FULL = FULL_TEMPLATE.replace("drives/servo.eds", str(CONFIG_DIR.parent / "eds" / "nurbsmotion-servo.eds"))
LAUGHS = "".join(f"{c}: &{c} [" + ", ".join([f"*{p}"] * 9) + "]\n" for p, c in zip("abcdefgh", "bcdefghi"))
YAML_VALUES = GARBAGE + [
    "~", "null", "[]", "{}", "[1, [2, [3]]]", "{a: 1}", "!!binary aGVsbG8=", "!!python/object:os.system ls",
    "!!set {a, b}", "*nowhere", "&anchor 5", "1e400", "1.0e400", "0x10", "0o17", "0b101", ".inf", "-.inf", ".nan",
    "1_000", "'\\ud800'", "\"\\ud800\"", "2026-11-22", "12:30:00", "yes", "no", "on", "'1'", "\"\"", "''",
    "9" * 400, "-" + "9" * 30, "1.5e-320", "[" * 200 + "]" * 200, "|\n  block", ">-",
    "{" * 50 + "}" * 50, "é", "\t", "a: b: c", "- - -", "? x", "!<tag:yaml.org,2002:str> x", "!!int 1.5",
    "!!float x", "*i", "\x00", "a\x07b", "\ufeff", "\x85",
]
_VALUE = re.compile(r"(?<=: )[^,}\]\n]+|(?<=\[)[^,\]\n]+|(?<=, )[^,\]}\n]+")


def mutate_value(text: str, rng: random.Random) -> str:
    """Replace one value (after 'key: ', in a flow list) by something of another kind."""
    spots = list(_VALUE.finditer(text))
    if not spots:
        return text
    m = rng.choice(spots)
    value = rng.choice(YAML_VALUES)
    if value == "*i":  # an alias of an exponentially large list (9^8 entries if expanded)
        text = "a: &a [x, x, x, x, x, x, x, x, x]\n" + LAUGHS + text
    return text[:m.start()] + value + text[m.end():]


def check(text: str) -> bool:
    """True if accepted; otherwise asserts a proper InputError."""
    try:
        config = parse_config(text, SOURCE, base_dir=CONFIG_DIR)  # the seeds' EDS paths are relative to config/
    except InputError as err:
        message = str(err)
        assert message, f"empty error for {text!r}"
        for line in message.splitlines():
            assert line.startswith(SOURCE), f"{line[:200]!r} does not name {SOURCE} (input {text[:300]!r})"
            assert len(line) <= MAX_LINE, f"a {len(line)}-character error line (input {text[:300]!r})"
        return False
    assert isinstance(config, MachineConfig) and config.axes
    return True


def seeds() -> list[str]:
    return [p.read_text() for p in sorted(CONFIG_DIR.glob("*.yaml"))] + [FULL]


def test_the_seed_configurations_are_valid():
    assert all(check(text) for text in seeds())


@pytest.mark.parametrize("mutation", ["characters", "values"])
def test_mutated_configs_are_accepted_or_rejected_cleanly(mutation):
    rng = random.Random(f"config-{mutation}")
    texts = seeds()
    accepted = 0
    for _ in range(CASES):
        text = rng.choice(texts)
        if mutation == "characters":
            text = mutate(text, rng)
        else:
            for _ in range(rng.randint(1, 3)):
                text = mutate_value(text, rng)
        accepted += check(text)
    assert 0 < accepted < CASES  # both outcomes are exercised


@pytest.mark.parametrize("depth", [10, 100, 1000, 10_000])
def test_deeply_nested_yaml_is_an_input_error(depth):
    for text in ("[" * depth + "]" * depth, "axes: " + "[" * depth + "]" * depth,
                 "axes:\n" + "".join("  " * i + "- \n" for i in range(min(depth, 2000)))):
        assert not check(text)


def test_an_exponential_alias_gives_a_short_error():
    text = "a: &a [x, x, x, x, x, x, x, x, x]\n" + LAUGHS + "cycle_period_ms: *i\naxes: [{name: X, node_id: 1}]\n"
    assert not check(text)


@pytest.mark.parametrize("text", ["\x00", "axes: [\x07]", "cycle_period_ms: !!int 1.5\naxes: []", "\ufeff\ufeffaxes: 1"])
def test_unreadable_characters_and_tags_are_one_located_line_each(text):
    assert not check(text)
