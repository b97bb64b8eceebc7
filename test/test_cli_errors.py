"""Every `memo-ros` failure is one line and exit 2: bad names, binary files, NaN, a closed pipe."""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys

ROOT = Path(__file__).resolve().parent.parent


def _cli(*args, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, '-m', 'memo_ros.tools.cli', *map(str, args)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        **kwargs,
    )


def _one_line_error(done: subprocess.CompletedProcess, words: str) -> None:
    assert done.returncode == 2, (done.returncode, done.stderr)
    lines = done.stderr.strip().splitlines()
    assert words in lines[-1], done.stderr
    assert 'Traceback' not in done.stderr and 'Error:' not in lines[-1], done.stderr


def test_record_refuses_an_invalid_topic_name(ros_env, tmp_path):
    done = ros_env.run('bag', 'record', '-o', tmp_path / 'bag', 'bad topic', '--duration', '1')
    _one_line_error(done, "'bad topic' is not a valid topic name")
    assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / 'bag').exists()


def test_a_binary_studio_or_params_file_is_one_line(tmp_path):
    binary = tmp_path / 'studio.yaml'
    binary.write_bytes(bytes(range(256)) * 8)
    done = _cli('launch', binary)
    _one_line_error(done, 'not a text (UTF-8) file')
    assert len(done.stderr.strip().splitlines()) == 1
    done = _cli('replay', tmp_path, '--studio', binary, '--out', tmp_path / 'out')
    assert done.returncode == 2 and 'Traceback' not in done.stderr


def test_simulate_refuses_a_rate_that_is_not_a_finite_positive_number(tmp_path):
    for rate in ('nan', 'inf', '-5', '0'):
        done = _cli('simulate', 'studio-arm', '--rate', rate, '--out', tmp_path / 'bag')
        _one_line_error(done, f'must be a finite number > 0, not {rate}')
    assert not (tmp_path / 'bag').exists()


def test_evaluate_errors_exit_2_like_the_other_commands(tmp_path):
    done = _cli('evaluate', '--truth', tmp_path / 'none', '--estimate', tmp_path / 'none')
    _one_line_error(done, 'no bag at')


def test_bag_info_into_a_closed_pipe_ends_quietly(tmp_path):
    bag = tmp_path / 'bag'
    done = _cli('simulate', 'studio-arm', '--frames', '2', '--out', bag)
    assert done.returncode == 0, done.stderr
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first line: every write hits EPIPE
    info = subprocess.Popen(
        [sys.executable, '-m', 'memo_ros.tools.cli', 'bag', 'info', str(bag)],
        cwd=ROOT,
        stdout=write_end,
        stderr=subprocess.PIPE,
        text=True,
    )
    os.close(write_end)
    _, err = info.communicate(timeout=60)
    assert 'BrokenPipeError' not in err and 'Traceback' not in err, err
    assert info.returncode == 0, err
