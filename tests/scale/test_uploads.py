"""The pure pieces of an upload through a front: the command's arguments, the copy's check,
the counting and hashing reader and writer, the waits and the errors' HTTP answers."""

from __future__ import annotations

import hashlib
import io
import os

import pytest
from nats.js.object_store import VALID_KEY_RE

from kybercore.api.errors import error_status
from kybercore.errors import InvalidInput, TransferFailed, UploadCorrupted
from kybercore.scale.commands import ACK_SECONDS, ANSWER_SECONDS
from kybercore.scale.uploads import (
    CHUNK_BYTES,
    HashingReader,
    HashingWriter,
    UploadOrder,
    answer_seconds,
    check_copy,
    fetch_seconds,
    object_name,
)
from kybercore.scale.wire import decode_error, dumps, encode_error, loads

MB = 1024 * 1024


def order(**changes: object) -> UploadOrder:
    fields: dict[str, object] = {
        "object": "upload-1", "size": 3, "sha256": hashlib.sha256(b"abc").hexdigest(),
        "filename": "dir/cube.gcode", "start": True, "confirm": False,
    }  # fmt: skip
    return UploadOrder(**{**fields, **changes})  # type: ignore[arg-type]


def test_an_order_crosses_as_plain_args() -> None:
    sent = order()
    assert UploadOrder.from_args(loads(dumps(sent.as_args()))) == sent
    assert UploadOrder.from_args({k: v for k, v in sent.as_args().items() if k != "start"}) == (
        order(start=False)
    )


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"size": "3"}, "size"),
        ({"size": True}, "size"),
        ({"start": "true"}, "start"),
        ({"sha256": None}, "sha256"),
        ({"object": 7}, "object"),
    ],
)
def test_a_malformed_order_is_refused_naming_the_field(
    changes: dict[str, object], field: str
) -> None:
    with pytest.raises(InvalidInput, match=f"'{field}'"):
        UploadOrder.from_args({**order().as_args(), **changes})


def test_a_missing_field_or_a_negative_size_is_refused() -> None:
    args = order().as_args()
    del args["sha256"]
    with pytest.raises(InvalidInput, match="lacks its 'sha256'"):
        UploadOrder.from_args(args)
    with pytest.raises(InvalidInput, match="negative"):
        UploadOrder.from_args({**order().as_args(), "size": -1})


def test_the_copy_must_be_the_file_sent() -> None:
    sent = order()
    check_copy(sent, 3, hashlib.sha256(b"abc").hexdigest(), "p1")  # the same: no error
    for size, digest in ((4, sent.sha256), (3, hashlib.sha256(b"abd").hexdigest())):
        with pytest.raises(UploadCorrupted) as corrupted:
            check_copy(sent, size, digest, "p1")
        assert corrupted.value.code == "upload_corrupted"
        assert corrupted.value.message.startswith("p1: the copy of 'dir/cube.gcode'")
        assert "Nothing was uploaded or started" in corrupted.value.message


def test_the_reader_counts_and_hashes_what_the_store_reads() -> None:
    data = os.urandom(3 * CHUNK_BYTES + 123)
    source = io.BytesIO(b"skipped" + data)
    source.seek(len(b"skipped"))  # read from where the file stands, as serve does
    reader = HashingReader(source)
    chunk, read = bytearray(CHUNK_BYTES), bytearray()
    while n := reader.readinto(chunk):
        read += chunk[:n]
    assert bytes(read) == data
    assert (reader.size, reader.hexdigest()) == (len(data), hashlib.sha256(data).hexdigest())
    assert reader.readable()
    assert isinstance(reader, io.BufferedIOBase)  # nats-py reads it in a thread only then


def test_the_writer_counts_and_hashes_what_the_store_writes() -> None:
    target = io.BytesIO()
    writer = HashingWriter(target)
    parts = [b"G28\n", bytearray(b"G1 X10\n"), memoryview(b"M84\n")]
    for part in parts:
        writer.write(part)
    whole = b"G28\nG1 X10\nM84\n"
    assert target.getvalue() == whole
    assert (writer.size, writer.hexdigest()) == (len(whole), hashlib.sha256(whole).hexdigest())
    assert writer.writable()
    assert not hasattr(writer, "buffer")  # else nats-py would write to that instead


def test_object_names_are_unique_and_valid_keys() -> None:
    names = {object_name() for _ in range(1000)}
    assert len(names) == 1000
    assert all(VALID_KEY_RE.match(name) for name in names)


def test_waits_grow_with_the_file_and_the_ack_does_not() -> None:
    assert answer_seconds(0) == ANSWER_SECONDS  # a command's time, at least
    # 512 MB (the upload limit): fetched, then sent to a printer, each at 1 MB/s or better.
    assert answer_seconds(512 * MB) >= ANSWER_SECONDS + 2 * 512
    assert answer_seconds(100 * MB) < answer_seconds(101 * MB)
    assert fetch_seconds(100 * MB) >= 100
    assert ACK_SECONDS <= 5  # the owner takes the command at once, whatever the size


def test_transfer_errors_cross_nats_and_answer_retry() -> None:
    for exc in (
        TransferFailed("the broker went away", printer="p1"),
        UploadCorrupted("the copy differs", printer="p1"),
    ):
        back = decode_error(loads(dumps(encode_error(exc))))
        assert type(back) is type(exc)
        assert (back.code, back.message) == (exc.code, exc.message)
        assert error_status(back) == (503, exc.code)
