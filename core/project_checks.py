"""What an HDF5 file must not contain for volucal to read it as a project.

A project is read whole into memory (:mod:`.project`). Before any value is read, the file's
structure is walked without following a single link, and refused with one line when it holds:

- an **external link** (it would make volucal open another file — any file the link names — and
  embed what it reads into the project at the next save);
- a **soft link** (volucal never writes one; a soft link to a parent group makes a cycle that the
  reader would follow forever) or a second hard link to an object already seen (a hard-link
  cycle);
- a dataset with **external storage** (its values live in another file, e.g. /etc/passwd) or a
  **virtual dataset** (its values are mapped from other datasets or files);
- a dataset larger than :data:`MAX_DATASET_BYTES`, datasets larger than
  :data:`MAX_TOTAL_BYTES` together, or a dataset that claims more than
  :data:`MIN_STORED_FRACTION` of its size without storing it (a 4.8 MB file can declare an
  unwritten 16 GB dataset that HDF5 would fill with zeros on reading).

volucal writes none of these, so a file that has one was made or altered by something else.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np

from .userror import UserError

#: Largest dataset volucal reads (bytes in memory): a capture of 10⁸ samples is 0.8 GB.
MAX_DATASET_BYTES = 1 << 30
#: Largest total of all datasets of a project (bytes in memory).
MAX_TOTAL_BYTES = 4 << 30
#: A dataset above :data:`SMALL_DATASET_BYTES` must have at least this fraction of its size
#: stored in the file. volucal writes no compression, so its datasets store all their bytes.
MIN_STORED_FRACTION = 0.1
SMALL_DATASET_BYTES = 1 << 20


def check_structure(handle: h5py.File, path: str | Path) -> None:
    """Raise :class:`UserError` when the open file holds anything of the module notes."""
    seen: dict[tuple[int, ...], str] = {}
    total = 0

    def refuse(where: str, what: str) -> UserError:
        return UserError(
            f"{path}: {where} {what}; volucal projects hold none, so this file was made or "
            "changed by another program and is not read"
        )

    def walk(group: h5py.Group, prefix: str) -> None:
        nonlocal total
        for name in group:
            where = f"{prefix}/{name}" if prefix != "/" else f"/{name}"
            link = group.get(name, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                raise refuse(where, f"is an external link to {link.filename}:{link.path}")
            if isinstance(link, h5py.SoftLink):
                raise refuse(where, f"is a soft link to {link.path}")
            item = group.get(name)
            if item is None:
                raise refuse(where, "is a link to nothing")
            identity = _identity(item)
            if identity in seen:
                raise refuse(
                    where,
                    f"is a second link to {seen[identity]} (a hard-link cycle or a shared object)",
                )
            seen[identity] = where
            if isinstance(item, h5py.Group):
                walk(item, where)
            elif isinstance(item, h5py.Dataset):
                total += _check_dataset(item, where, refuse)
                if total > MAX_TOTAL_BYTES:
                    raise UserError(
                        f"{path}: the datasets hold more than {_size(MAX_TOTAL_BYTES)} together "
                        "(the most volucal reads from one project); it is not read"
                    )
            else:
                raise refuse(where, f"is an HDF5 {type(item).__name__}")

    walk(handle, "/")


def _identity(item: h5py.HLObject) -> tuple[int, ...]:
    info = h5py.h5o.get_info(item.id)
    token = getattr(info, "token", None)  # HDF5 1.12+: an opaque token instead of an address
    if token is not None:
        return (info.fileno, *bytes(token))
    return (info.fileno, int(info.addr))


def _check_dataset(data: h5py.Dataset, where: str, refuse: Callable[[str, str], UserError]) -> int:
    plist = data.id.get_create_plist()
    if plist.get_layout() == h5py.h5d.VIRTUAL:
        raise refuse(where, "is a virtual dataset (its values come from other files)")
    if plist.get_external_count() > 0:
        name = plist.get_external(0)[0].decode("utf-8", "replace")
        raise refuse(where, f"keeps its values in an external file ({name})")
    itemsize = data.dtype.itemsize if data.dtype.kind != "O" else 16
    size = int(np.prod(data.shape, dtype=np.float64) * itemsize) if data.shape else itemsize
    if size > MAX_DATASET_BYTES:
        raise UserError(
            f"{data.file.filename}: {where} declares {_size(size)}, more than the "
            f"{_size(MAX_DATASET_BYTES)} volucal reads from one dataset; it is not read"
        )
    if data.dtype.kind != "O" and size > SMALL_DATASET_BYTES:
        stored = data.id.get_storage_size()
        if stored < MIN_STORED_FRACTION * size:
            raise UserError(
                f"{data.file.filename}: {where} declares {_size(size)} but stores only "
                f"{_size(stored)} in the file (unwritten or compressed far beyond what volucal "
                "writes); it is not read"
            )
    return size


def _size(count: float) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if count >= scale:
            return f"{count / scale:.3g} {unit}"
    return f"{int(count)} bytes"
