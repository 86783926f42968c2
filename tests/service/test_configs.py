"""The example configurations of the service load."""

from pathlib import Path

from nurbsmotion.config import ControlConfig, load_config

ROOT = Path(__file__).resolve().parents[2]


def test_vcan_config_is_socketcan_without_in_process_drives():
    cfg = load_config(ROOT / "config" / "vcan.yaml")
    assert (cfg.bus.interface, cfg.bus.channel, cfg.simulate) == ("socketcan", "vcan0", False)
    assert cfg.axis_names() == ("X", "Y", "Z") and abs(cfg.cycle_period_s - 0.004) < 1e-12


def test_every_shipped_config_serves_the_clients_default_socket():
    """Issue 15: every client command needed --config because no shipped config used the
    default socket."""
    default = ControlConfig().socket
    for path in [*(ROOT / "config").glob("*.yaml"), ROOT / "src" / "nurbsmotion" / "data" / "demo.yaml"]:
        assert load_config(path).control.socket == default, path
