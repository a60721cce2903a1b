"""Streams of a run: ``-`` and ``tcp://`` sources, inputs and outputs checked apart, outputs staged
until the run starts, signals deferred while a line is written, replay paced at stream time."""
import json
import os
import signal
import socket
import threading

import pytest

from estimator.observations import ObservationReader
from experiments.streams import (
    STDIN_NAME,
    LineOutput,
    PathOption,
    StagedFile,
    StopSignals,
    Terminated,
    check_paths,
    open_observations,
    paced,
    parse_tcp,
    write_text,
)
from physics.errors import InputError


def test_tcp_addresses():
    assert parse_tcp("tcp://127.0.0.1:9000") == ("127.0.0.1", 9000)
    assert parse_tcp("tcp://[::1]:9000/") == ("::1", 9000)
    assert parse_tcp("frames.jsonl") is None and parse_tcp("-") is None
    for bad in ("tcp://host", "tcp://:9000", "tcp://host:0", "tcp://host:http", "tcp://host:70000"):
        with pytest.raises(InputError, match=r"^--observations: expected tcp://HOST:PORT"):
            parse_tcp(bad)


def test_stdin_is_named_in_messages():
    name, stream = open_observations("-")
    try:
        assert name == STDIN_NAME == "<stdin>" and stream is not None
    finally:
        stream.close()
    assert open_observations("obs.jsonl") == ("obs.jsonl", None)  # the reader opens paths itself


def test_a_tcp_source_is_read_line_by_line_as_it_comes():
    """The server sends the next line only once the reader has yielded the previous frame: a reader
    that waited for more than a line would hang here (the join's timeout fails the test)."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    got = []
    read = threading.Event()

    def serve():
        conn, _ = server.accept()
        with conn:
            for k in range(5):
                conn.sendall((json.dumps({"t": k / 10, "objects": {"cup": {"position": [0, 0, 1]}}}) + "\n").encode())
                assert read.wait(30)
                read.clear()

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    name, stream = open_observations(f"tcp://127.0.0.1:{port}")
    for frame in ObservationReader(name, ["cup"], stream=stream):
        got.append(frame.t)
        read.set()
    th.join(30)
    server.close()
    assert got == [0.0, 0.1, 0.2, 0.3, 0.4] and not th.is_alive()


def test_a_refused_connection_is_a_located_error():
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(InputError, match=rf"^--observations: cannot connect to tcp://127.0.0.1:{port}"):
        open_observations(f"tcp://127.0.0.1:{port}")


def test_an_output_that_is_an_input_or_another_output_is_refused(tmp_path):
    obs = tmp_path / "o.jsonl"
    obs.write_text("{}\n")
    (tmp_path / "link.jsonl").symlink_to(obs)
    os.link(obs, tmp_path / "hard.jsonl")
    (tmp_path / "sub").mkdir()
    (tmp_path / "dirlink").symlink_to(tmp_path / "sub")
    inputs = [PathOption("--scene", str(tmp_path / "s.yaml")), PathOption("--observations", str(obs))]
    for same in (obs, tmp_path / "link.jsonl", tmp_path / "hard.jsonl", tmp_path / "sub" / ".." / "o.jsonl"):
        with pytest.raises(InputError, match=r"^--out: .* is the same file as --observations .*an input"):
            check_paths(inputs, [PathOption("--out", str(same))])
    # two outputs on one file that does not exist yet, through a linked folder
    with pytest.raises(InputError, match=r"^--timeline: .*same file as --out .*another output"):
        check_paths(inputs, [PathOption("--out", str(tmp_path / "sub" / "e.json")),
                             PathOption("--timeline", str(tmp_path / "dirlink" / "e.json"))])
    with pytest.raises(InputError, match=r"^--timeline: standard output \(-\) is already --out"):
        check_paths(inputs, [PathOption("--out", "-"), PathOption("--timeline", "-")])
    # fine: distinct files, standard streams, a device written twice, options not given
    check_paths([PathOption("--observations", "-"), PathOption("--bag", None)],
                [PathOption("--out", "-"), PathOption("--timeline", os.devnull), PathOption("--rerun", os.devnull),
                 PathOption("--bag-out", None)])
    check_paths(inputs, [PathOption("--out", str(tmp_path / "e.jsonl")), PathOption("--timeline", str(tmp_path / "t.json"))])
    assert obs.read_text() == "{}\n"


def test_a_staged_file_replaces_its_path_only_when_committed(tmp_path):
    target = tmp_path / "e.jsonl"
    target.write_text("old\n")
    os.chmod(target, 0o640)
    staged = StagedFile(str(target))
    with open(staged.write_path, "w") as fh:
        fh.write("new\n")
    assert target.read_text() == "old\n" and os.path.dirname(staged.write_path) == str(tmp_path)
    staged.discard()  # the run never started
    assert target.read_text() == "old\n" and os.listdir(tmp_path) == ["e.jsonl"]
    staged = StagedFile(str(target))
    fh = open(staged.write_path, "w")
    fh.write("new\n")
    staged.commit()
    fh.write("more\n")  # written after the rename: it lands in the file
    fh.close()
    staged.discard()
    assert target.read_text() == "new\nmore\n" and os.listdir(tmp_path) == ["e.jsonl"]
    assert os.stat(target).st_mode & 0o777 == 0o640  # the replaced file's permissions are kept


def test_a_link_is_followed_and_a_fifo_written_directly(tmp_path):
    real = tmp_path / "real.jsonl"
    real.write_text("old\n")
    (tmp_path / "link.jsonl").symlink_to(real)
    staged = StagedFile(str(tmp_path / "link.jsonl"))
    with open(staged.write_path, "w") as fh:
        fh.write("new\n")
    staged.commit()
    assert (tmp_path / "link.jsonl").is_symlink() and real.read_text() == "new\n"
    os.mkfifo(tmp_path / "fifo")
    staged = StagedFile(str(tmp_path / "fifo"))
    assert staged.direct and staged.write_path == str(tmp_path / "fifo")
    with pytest.raises(InputError, match=r"^--out: cannot write"):
        StagedFile(str(tmp_path / "missing" / "e.jsonl"), "--out")


def test_line_output_before_and_after_the_start(tmp_path, capsys):
    target = tmp_path / "e.jsonl"
    target.write_text("old\n")
    out = LineOutput(str(target))
    out.close()  # never started
    assert target.read_text() == "old\n" and os.listdir(tmp_path) == ["e.jsonl"]
    out = LineOutput(str(target))
    out.start()
    out.write('{"t": 0}')
    assert target.read_text() == '{"t": 0}\n'  # flushed at once
    out.close()
    out = LineOutput("-")
    out.start()
    out.write('{"t": 1}')
    out.close()
    assert capsys.readouterr().out == '{"t": 1}\n'


def test_write_text_replaces_a_document_whole(tmp_path, capsys):
    write_text(str(tmp_path / "t.json"), '{"a": 1}\n')
    assert (tmp_path / "t.json").read_text() == '{"a": 1}\n' and os.listdir(tmp_path) == ["t.json"]
    write_text("-", '{"b": 2}\n')
    assert capsys.readouterr().out == '{"b": 2}\n'


def test_signals_raise_except_while_deferred():
    with StopSignals() as signals:
        before = signal.getsignal(signal.SIGTERM)
        with pytest.raises(Terminated):  # raised where the main thread is
            os.kill(os.getpid(), signal.SIGTERM)
        done = []
        with pytest.raises(KeyboardInterrupt):
            with signals.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                with signals.deferred():  # nested: raised at the end of the outermost block
                    done.append("inner")
                done.append("outer")  # the block runs to its end
        assert done == ["inner", "outer"]
    assert signal.getsignal(signal.SIGTERM) != before  # put back


class _Clock:
    def __init__(self):
        self.now = 100.0
        self.sleeps = []

    def __call__(self):
        return self.now

    def sleep(self, s):
        self.sleeps.append(round(s, 9))
        self.now += s


class _F:
    def __init__(self, t):
        self.t = t


def test_paced_replay_waits_for_stream_time_and_never_for_late_frames():
    clock = _Clock()
    out = []
    for f in paced([_F(1.0), _F(1.5), _F(2.0), _F(2.1)], speed=2.0, clock=clock, sleep=clock.sleep):
        out.append((f.t, clock.now))
        if f.t == 1.5:
            clock.now += 0.4  # the consumer took longer than the stream's pace: the next frames are late
    assert out == [(1.0, 100.0), (1.5, 100.25), (2.0, 100.65), (2.1, 100.65)]
    assert clock.sleeps == [0.25]
    with pytest.raises(ValueError, match="speed must be > 0"):
        list(paced([_F(0.0)], speed=0.0))
