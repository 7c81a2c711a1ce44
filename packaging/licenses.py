"""The third-party licence file of the frozen build (THIRD_PARTY_LICENSES.txt).

The PyInstaller spec passes the names of the modules it bundled; each top-level module is traced
to the distribution that installed it (``importlib.metadata.packages_distributions``) and the
licence texts those distributions ship (``License-File`` entries and LICENSE/COPYING/NOTICE files
in their records) are copied into one text file, with the licence declared in the metadata. A
distribution that ships no text (PySide6 and shiboken6 wheels) gets the text of the licence its
metadata names from the system's licence folder when there is one (Debian's
/usr/share/common-licenses). The Python interpreter's own licence comes first, since the bundle
carries the interpreter.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterable
from importlib import metadata
from pathlib import Path

#: Files whose name says they are a licence text.
LICENSE_NAME = re.compile(r"(^|/)(LICEN[CS]E|COPYING|NOTICE)[^/]*$", re.IGNORECASE)
#: Where Debian keeps the full texts of common licences (by SPDX-like short names).
COMMON_LICENSES = Path("/usr/share/common-licenses")
#: SPDX ids (prefix match) and the common-licenses files holding their text. LGPL-3.0 is a set
#: of permissions added to the GPL-3.0, so its text needs the GPL's beside it.
SPDX_TEXTS = {
    "LGPL-3.0": ("LGPL-3", "GPL-3"),
    "LGPL-2.1": ("LGPL-2.1",),
    "GPL-3.0": ("GPL-3",),
    "GPL-2.0": ("GPL-2",),
    "Apache-2.0": ("Apache-2.0",),
    "MPL-2.0": ("MPL-2.0",),
}
RULE = "=" * 100


def bundled_distributions(module_names: Iterable[str], exclude: Iterable[str] = ()) -> list[
        metadata.Distribution]:
    """The installed distributions that provide the given modules (dotted names allowed),
    sorted by name, without those named in ``exclude``."""
    providers = metadata.packages_distributions()
    skip = {_normal(n) for n in exclude}
    names: set[str] = set()
    for module in module_names:
        for provider in providers.get(module.split(".")[0], ()):
            if _normal(provider) not in skip:
                names.add(provider)
    found = {}
    for name in names:
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue
        found[_normal(_field(dist, "Name") or name)] = dist
    return [found[k] for k in sorted(found)]


def _field(dist: metadata.Distribution, key: str) -> str | None:
    """One metadata field, or None."""
    values = dist.metadata.get_all(key) or []
    return str(values[0]) if values else None


def declared_license(dist: metadata.Distribution) -> str:
    """The licence the distribution's metadata declares (expression, field or classifiers)."""
    expression = _field(dist, "License-Expression")
    if expression:
        return expression
    field = (_field(dist, "License") or "").strip()
    if field and "\n" not in field and len(field) < 200:
        return field
    classifiers = [c.split("::")[-1].strip() for c in dist.metadata.get_all("Classifier") or []
                   if c.startswith("License ::")]
    if classifiers:
        return "; ".join(classifiers)
    return field.splitlines()[0] if field else "not declared"


def license_texts(dist: metadata.Distribution) -> list[tuple[str, str]]:
    """(file name, text) of every licence text the distribution installed."""
    out = []
    seen: set[str] = set()
    for entry in dist.files or ():
        name = str(entry)
        if not LICENSE_NAME.search(name) or name in seen:
            continue
        path = Path(str(dist.locate_file(entry)))
        if path.is_file():
            seen.add(name)
            out.append((name, path.read_text(encoding="utf-8", errors="replace")))
    return out


def common_license_texts(declared: str) -> list[tuple[str, str]]:
    """Texts from :data:`COMMON_LICENSES` for the first SPDX id of ``declared`` it knows."""
    for spdx, files in SPDX_TEXTS.items():
        if spdx in declared:
            paths = [COMMON_LICENSES / f for f in files]
            if all(p.is_file() for p in paths):
                return [(str(p), p.read_text(encoding="utf-8", errors="replace")) for p in paths]
            return []
    return []


def python_license() -> tuple[str, str] | None:
    """The interpreter's LICENSE.txt, where the installation keeps it."""
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    for root in (Path(sys.base_prefix), Path(sys.prefix)):
        for candidate in (root / "lib" / version / "LICENSE.txt", root / "LICENSE.txt"):
            if candidate.is_file():
                return str(candidate), candidate.read_text(encoding="utf-8", errors="replace")
    return None


def third_party_text(module_names: Iterable[str], own: str = "volucal") -> str:
    """The whole licence file for a bundle of ``module_names`` (``own`` is left out)."""
    dists = bundled_distributions(module_names, exclude=[own])
    parts = [
        f"Third-party software bundled with {own}",
        "",
        f"This folder holds the Python {sys.version.split()[0]} interpreter and the "
        "distributions listed below, each under its own licence, reproduced here. The Qt "
        "libraries come with PySide6 as shared libraries that can be replaced (LGPL-3.0).",
        "",
    ]
    for dist in dists:
        parts.append(f"  {_field(dist, 'Name')} {dist.version}: {declared_license(dist)}")
    python = python_license()
    if python is not None:
        parts += ["", RULE, f"Python {sys.version.split()[0]} ({python[0]})", RULE, "",
                  python[1].rstrip()]
    for dist in dists:
        declared = declared_license(dist)
        home = _field(dist, "Home-page") or next(
            (u.split(",", 1)[-1].strip() for u in dist.metadata.get_all("Project-URL") or []),
            "")
        parts += ["", RULE, f"{_field(dist, 'Name')} {dist.version}", f"Licence: {declared}"]
        if home:
            parts.append(f"Home: {home}")
        parts += [RULE]
        texts = license_texts(dist) or common_license_texts(declared)
        if not texts:
            parts += ["", "(the distribution ships no licence text; its declared licence is "
                      "named above)"]
        for name, text in texts:
            parts += ["", f"--- {name} ---", "", text.rstrip()]
    return "\n".join(parts) + "\n"


def write_third_party_licenses(path: Path, module_names: Iterable[str],
                               own: str = "volucal") -> Path:
    path = Path(path)
    path.write_text(third_party_text(module_names, own), encoding="utf-8")
    return path


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()
