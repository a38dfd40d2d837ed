"""Outputs that never cost data: every file is written under a temporary name in its own folder and
renamed into place only when complete, and a target is checked before any work starts (not one of
the inputs, its folder there and writable, its suffix one the format can take). '-' is standard output.
A symbolic link is written through, at the file it names (renamed into place there, the link kept); a
character device or a pipe (/dev/null, a FIFO, /dev/stdout) is written directly, as a stream, since
renaming over it would put a file in its place; a block device or a socket is refused by name.
A request too large for memory is refused up front too, saying how much it would need.
"""

from __future__ import annotations

import errno
import os
import stat
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

from .errors import JmlgError

FIGURE = (".png", ".pdf", ".svg", ".eps", ".ps")
MODEL = (".json", ".npz", ".mat")


def _identities(path: Path) -> set:
    """What names the file at `path`: its resolved path, and its device and inode where it exists (so
    two hard links to one file are one file). Two paths name one file when these meet."""
    found = {path.resolve()}
    try:
        status = os.stat(path)
    except OSError:
        return found
    return found | {(status.st_dev, status.st_ino)}


def _followed(path: Path) -> tuple[Path, bool]:
    """The file `path` names once its symbolic links are followed, and whether one of them is an open
    descriptor's (/dev/stdout, /proc/self/fd/1): such a link names the open file itself, wherever it is
    (a redirected output), so it is written in place, after what it holds (`>> file`), never renamed
    over."""
    for _ in range(40):  # the kernel's own limit on links in a row
        path = Path(os.path.realpath(path.parent)) / path.name
        if not path.is_symlink():
            return path, False
        if path.parts[1:2] == ("proc",):
            return path, True
        path = path.parent / os.readlink(path)
    raise JmlgError(f"cannot write {path}: {os.strerror(errno.ELOOP)}")


def _destination(path) -> tuple[Path, bool]:
    """Where `path` is written, and whether directly (True: a stream opened on it) or through a
    temporary file renamed onto it (False: a regular file or a new one, at the end of its links).
    A block device, a socket or anything else that is neither is refused by name."""
    followed, descriptor = _followed(Path(path))
    try:
        mode = os.stat(path).st_mode  # through the links, as the write would go
    except (FileNotFoundError, NotADirectoryError):
        return followed, False
    if stat.S_ISREG(mode):
        return (Path(path), True) if descriptor else (followed, False)
    if stat.S_ISCHR(mode) or stat.S_ISFIFO(mode):
        return Path(path), True
    kind = "a block device (a disk)" if stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode) else \
        "a folder" if stat.S_ISDIR(mode) else "not a file"
    raise JmlgError(f"cannot write {path}: it is {kind}; give a file, a pipe or a character device such as "
                    "/dev/stdout")


def _writable_folder(folder: Path, path):
    """Refuse a folder that is missing, is not a folder, or cannot be written to, in the words the
    system would use when the write failed. A file is made and removed there too: permissions do not
    stop a superuser, yet a folder like /proc still refuses new files."""
    for failed, code, why in ((not folder.exists(), errno.ENOENT, f"no folder {folder}"),
                              (not folder.is_dir(), errno.ENOTDIR, f"{folder} is a file"),
                              (not os.access(folder, os.W_OK | os.X_OK), errno.EACCES,
                               f"folder {folder} is not writable")):
        if failed:
            raise JmlgError(f"cannot write {path}: {os.strerror(code)} ({why})")
    try:
        fd, probe = tempfile.mkstemp(prefix=".jmlgdsl-probe.", dir=folder)
    except OSError as exc:
        raise JmlgError(f"cannot write {path}: {exc.strerror or exc} (folder {folder} takes no new files)") from None
    os.close(fd)
    os.unlink(probe)


def _not_an_input(paths, inputs, what: str):
    """Refuse outputs that are one of the inputs: writing one would destroy the data it is made from.
    Each path is looked at once, however many outputs and inputs (a fleet's hundreds of files) there are."""
    given = {}
    for name in inputs:
        if name is not None and str(name) != "-":
            for identity in _identities(Path(name)):
                given.setdefault(identity, name)
    for path in paths:
        found = next((given[identity] for identity in _identities(path) if identity in given), None)
        if found is not None:
            raise JmlgError(f"{what}: {path} is also an input ({found}); writing it would destroy it, "
                            "so choose another file")


def check_file(path, inputs=(), suffixes=None, option="-o") -> None:
    """Refuse, before any work, an output file that cannot or must not be written: one of `inputs`,
    a folder, a read-only file, one in a missing or unwritable folder, or a suffix not in `suffixes`."""
    if path is None or str(path) == "-":
        if path is not None and sys.stdout is None:
            raise JmlgError(f"{option} -: standard output is closed")
        return
    path, what = Path(path), f"{option} {path}"
    if suffixes and path.suffix.lower() not in suffixes:
        raise JmlgError(f"{what}: the file name must end in {', '.join(suffixes)}")
    if path.is_dir():
        raise JmlgError(f"{what}: {path} is a folder; give a file name")
    target, direct = _destination(path)
    if not direct:
        _writable_folder(target.parent, path)
    if target.exists() and not os.access(target, os.W_OK):
        raise JmlgError(f"cannot write {path}: {os.strerror(errno.EACCES)} (the file is read-only)")
    _not_an_input([path], inputs, what)


def check_folder(path, names=(), inputs=(), option="-o") -> None:
    """Refuse, before any work, an output folder that is a file or cannot be made or written, or
    where a file the command writes (`names`) would be one of `inputs`."""
    path, what = Path(path), f"{option} {path}"
    if path.exists() and not path.is_dir():
        raise JmlgError(f"{what}: {path} is a file, not a folder")
    _writable_folder(next(p for p in (path, *path.absolute().parents) if p.exists()), path)
    _not_an_input([path / name for name in names], inputs, what)


def is_folder(path) -> bool:
    """Whether an output `path` names a folder: it ends in a separator or is an existing folder."""
    return str(path).endswith(("/", os.sep)) or os.path.isdir(path)


def file_names(paths, suffix: str, what: str) -> list[str]:
    """The file each of `paths` gives its `what` (a table, a unit spec), NAME+suffix for a file NAME.*:
    a JmlgError for standard input, which has no name, or for two files that would write the same one."""
    if "-" in paths:
        raise JmlgError(f"standard input (-) has no name to give its {what}; give files")
    names = [Path(path).stem + suffix for path in paths]
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise JmlgError(f"two data files would write the same {what} {twice[0]}; give files with different names")
    return names


def physical_memory() -> int:
    """Bytes of memory this machine has (8 GiB where the system does not say)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return 8 << 30


def _size(nbytes: float) -> str:
    """A byte count for people: '37.3 GiB'."""
    for unit, shift in (("TiB", 40), ("GiB", 30), ("MiB", 20)):
        if nbytes >= 1 << shift:
            return f"{nbytes / (1 << shift):.1f} {unit}"
    return f"{nbytes / 1024:.1f} KiB"


def check_count(option, count, bytes_each, unit="") -> None:
    """Refuse a count (of steps, particles, runs) that is not positive, or whose arrays, `bytes_each`
    per unit, would need more memory than this machine has; the message says how much it would need."""
    if count < 1:
        raise JmlgError(f"{option} must be a positive number{' of ' + unit if unit else ''}, got {count}")
    need, have = count * bytes_each, physical_memory()
    if need > have:
        raise JmlgError(f"{option} {count:,} would need about {_size(need)} of memory; this machine has "
                        f"{_size(have)}")


def _temporary(target: Path) -> tuple[int, Path]:
    """A new file beside `target` (same folder, same suffix, so a writer that reads the format from
    the suffix still can): its descriptor and path."""
    fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix, dir=target.parent)
    return fd, Path(name)


def _commit(temporary: Path, target: Path):
    """Rename a finished temporary file into place, with the permissions a new file would get."""
    umask = os.umask(0)
    os.umask(umask)
    mode = target.stat().st_mode & 0o7777 if target.exists() else 0o666 & ~umask
    os.chmod(temporary, mode)
    os.replace(temporary, target)


@contextmanager
def replacing(path):
    """A temporary path to write `path` through: renamed onto `path` when the block completes, removed
    if it raises, so `path` holds either its old content or the whole new one. Through a symbolic link
    the file it names is replaced; a pipe or a character device is itself the path written to."""
    target, direct = _destination(path)
    if direct:
        yield target
        return
    try:
        fd, temporary = _temporary(target)
    except OSError as exc:
        raise JmlgError(f"cannot write {path}: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        yield temporary
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    _commit(temporary, target)


@contextmanager
def writing(path):
    """A text stream to write `path` through, whole or not at all (see `replacing`); '-' is standard
    output, flushed at the end and left open."""
    if str(path) == "-":
        if sys.stdout is None:
            raise JmlgError("cannot write to standard output: it is closed")
        yield sys.stdout
        sys.stdout.flush()
        return
    target, direct = _destination(path)
    if direct:  # a pipe, a device or an open descriptor: written as it comes, after what it holds
        with open(target, "a", encoding="utf-8", newline="") as stream:
            yield stream
        return
    with replacing(target) as temporary, open(temporary, "w", encoding="utf-8", newline="") as stream:
        yield stream
