"""The example configurations of the service load."""

from pathlib import Path

from nurbsmotion.config import load_config

ROOT = Path(__file__).resolve().parents[2]


def test_vcan_config_is_socketcan_without_in_process_drives():
    cfg = load_config(ROOT / "config" / "vcan.yaml")
    assert (cfg.bus.interface, cfg.bus.channel, cfg.simulate) == ("socketcan", "vcan0", False)
    assert cfg.axis_names() == ("X", "Y", "Z") and abs(cfg.cycle_period_s - 0.004) < 1e-12
