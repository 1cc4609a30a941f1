"""The host talks to the simulated board in another process, through pyserial,
over a real pseudo-terminal or a loopback socket."""

import os
import stat
import subprocess
import sys

import pytest
import serial

from eskin.acquisition.session import simulated_board
from eskin.device.link import LinkError, SerialLink, list_serial_ports
from eskin.device.physics import SkinParams


def test_frames_cross_a_real_pty_from_another_process():
    with simulated_board(SkinParams(), rest_length_mm=101.0) as board:
        assert board.port.startswith("/dev/pts/")
        assert stat.S_ISCHR(os.stat(board.port).st_mode), "the port is a character device"
        assert board.process.pid != os.getpid()
        with SerialLink(board.port, timeout_s=1.0) as link:
            assert type(link._serial) is serial.Serial, "pyserial's own POSIX port, no shortcut"
            assert os.isatty(link._serial.fileno())
            hello = link.connect()
            batch = link.sample(500)
            assert batch.problem is None and len(batch.frames) == 500
            # The frames came from that process: once it is gone, nothing answers.
            board.process.kill()
            board.process.wait()
            with pytest.raises(LinkError, match=board.port):
                link.sample(10)
    assert hello.device_id.startswith("sim-")


def test_socket_transport_binds_loopback_and_speaks_the_same_protocol():
    with simulated_board(SkinParams(), rest_length_mm=101.0, socket_port=0) as board:
        assert board.port.startswith("socket://127.0.0.1:")
        with SerialLink(board.port) as link:
            link.connect()
            link.command("STRETCH 8.000")
            batch = link.sample(50)
    assert batch.problem is None and len(batch.frames) == 50


def test_silent_port_is_an_error_naming_the_port_not_a_hang():
    master, slave = os.openpty()
    port = os.ttyname(slave)
    try:
        with SerialLink(port, timeout_s=0.3) as link:
            try:
                link.connect()
            except Exception as err:  # noqa: BLE001
                assert port in str(err) and "silent" in str(err)
            else:
                raise AssertionError("a silent board must raise")
    finally:
        os.close(master)
        os.close(slave)


def test_missing_port_is_a_clear_error():
    try:
        SerialLink("/dev/does-not-exist")
    except Exception as err:  # noqa: BLE001
        assert "/dev/does-not-exist" in str(err)
    else:
        raise AssertionError


def test_ports_command_lists_through_pyserial():
    assert isinstance(list_serial_ports(), list)
    out = subprocess.run([sys.executable, "-m", "eskin", "ports"], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0 and out.stdout
