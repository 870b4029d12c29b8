"""An output reaches the disk before it takes its name: ``safe_io.atomic_path`` flushes the
finished temporary file to the device (``os.fsync``) and only then renames it over the
target, so a crash or a power cut after the rename never leaves an empty or partial file
under the user's name (no bpy)."""

import os

from vdnif_addon import safe_io


def test_the_temporary_is_synced_before_it_is_renamed(tmp_path, monkeypatch):
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        status = os.fstat(fd)
        events.append(("fsync", (status.st_dev, status.st_ino)))
        return real_fsync(fd)

    def replace(source, target):
        status = os.stat(source)
        events.append(("replace", (status.st_dev, status.st_ino), os.fspath(target)))
        return real_replace(source, target)

    monkeypatch.setattr(safe_io.os, "fsync", fsync)
    monkeypatch.setattr(safe_io.os, "replace", replace)
    target = tmp_path / "out.json"
    target.write_text("")                    # an empty file may be replaced
    safe_io.write_bytes_atomic(target, b"new", "JSON file")
    assert target.read_bytes() == b"new"
    renames = [event for event in events if event[0] == "replace"]
    assert len(renames) == 1 and renames[0][2] == str(target)
    temporary = renames[0][1]                 # the renamed file, by its device and inode
    synced = [index for index, event in enumerate(events)
              if event[0] == "fsync" and event[1] == temporary]
    assert synced and synced[0] < events.index(renames[0])
