"""Before Qt starts: are the system libraries its X11 (xcb) platform needs installed?

The PySide6 wheel brings Qt but not the X11 libraries of the desktop. On a fresh Debian or
Ubuntu machine some are missing (libxcb-icccm4, libxcb-keysyms1, libxcb-cursor0, …) and Qt then
aborts with a message that names only one of them ("xcb-cursor0 or libxcb-cursor0 is needed").
This check runs ``ldd`` on Qt's xcb platform plugin and its XcbQpa library, asks the dynamic
loader for the libraries Qt opens at run time (xcb-cursor), and names every missing library with
the Debian package that provides it and the ``apt-get`` line to type. It never imports Qt.
"""

from __future__ import annotations

import ctypes.util
import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

#: Debian/Ubuntu packages of the libraries Qt's xcb platform loads (soname → package).
DEBIAN_PACKAGES = {
    "libxcb-cursor.so.0": "libxcb-cursor0",
    "libxcb-icccm.so.4": "libxcb-icccm4",
    "libxcb-keysyms.so.1": "libxcb-keysyms1",
    "libxcb-image.so.0": "libxcb-image0",
    "libxcb-render-util.so.0": "libxcb-render-util0",
    "libxcb-randr.so.0": "libxcb-randr0",
    "libxcb-shape.so.0": "libxcb-shape0",
    "libxcb-xinerama.so.0": "libxcb-xinerama0",
    "libxcb-xinput.so.0": "libxcb-xinput0",
    "libxcb-xfixes.so.0": "libxcb-xfixes0",
    "libxcb-xkb.so.1": "libxcb-xkb1",
    "libxcb-sync.so.1": "libxcb-sync1",
    "libxcb-shm.so.0": "libxcb-shm0",
    "libxcb-render.so.0": "libxcb-render0",
    "libxcb-util.so.1": "libxcb-util1",
    "libxcb.so.1": "libxcb1",
    "libX11-xcb.so.1": "libx11-xcb1",
    "libX11.so.6": "libx11-6",
    "libxkbcommon-x11.so.0": "libxkbcommon-x11-0",
    "libxkbcommon.so.0": "libxkbcommon0",
    "libEGL.so.1": "libegl1",
    "libGL.so.1": "libgl1",
    "libOpenGL.so.0": "libopengl0",
    "libfontconfig.so.1": "libfontconfig1",
    "libfreetype.so.6": "libfreetype6",
    "libdbus-1.so.3": "libdbus-1-3",
    "libglib-2.0.so.0": "libglib2.0-0",
    "libSM.so.6": "libsm6",
    "libICE.so.6": "libice6",
}
#: Libraries Qt opens with dlopen (invisible to ldd): soname → name for ctypes.util.find_library.
LOADED_AT_RUN_TIME = {"libxcb-cursor.so.0": "xcb-cursor"}
_NOT_FOUND = re.compile(r"^\s*(\S+)\s*=>\s*not found", re.MULTILINE)
_CANNOT_OPEN = re.compile(r"(lib[\w.+-]+\.so[\w.]*): cannot open shared object file")


def qt_folder() -> Path | None:
    """PySide6's Qt folder (found without importing PySide6)."""
    spec = importlib.util.find_spec("PySide6")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0]) / "Qt"


def missing_from_ldd(output: str) -> list[str]:
    """The sonames ``ldd`` reports as "not found"."""
    return list(dict.fromkeys(_NOT_FOUND.findall(output)))


def missing_xcb_libraries(qt: Path | None = None) -> list[str]:
    """Sonames Qt's xcb platform needs that the dynamic loader cannot find."""
    qt = qt or qt_folder()
    if qt is None or shutil.which("ldd") is None:
        return []
    candidates = [qt / "plugins" / "platforms" / "libqxcb.so", qt / "lib" / "libQt6XcbQpa.so.6"]
    missing: list[str] = []
    for path in candidates:
        if not path.is_file():
            continue
        try:
            output = subprocess.run(["ldd", str(path)], capture_output=True, text=True,
                                    timeout=30).stdout
        except (OSError, subprocess.SubprocessError):
            continue
        missing += missing_from_ldd(output)
    for soname, name in LOADED_AT_RUN_TIME.items():
        if ctypes.util.find_library(name) is None:
            missing.append(soname)
    return list(dict.fromkeys(missing))


def packages_for(sonames: list[str]) -> list[str]:
    """Debian packages providing ``sonames`` (a guess from the name for an unknown one)."""
    out = []
    for soname in sonames:
        package = DEBIAN_PACKAGES.get(soname)
        if package is None:  # libfoo-bar.so.3 → libfoo-bar3
            stem, _, version = soname.partition(".so")
            package = stem.lower() + version.strip(".").split(".")[0]
        out.append(package)
    return list(dict.fromkeys(out))


def install_message(sonames: list[str]) -> str:
    """The message naming what to install."""
    packages = packages_for(sonames)
    return (
        "the workbench's X11 (xcb) platform needs system libraries that are not installed: "
        f"{', '.join(sonames)}. On Debian or Ubuntu install them with:\n"
        f"    sudo apt-get install {' '.join(packages)}\n"
        "(other systems: the packages providing these files). Without a display, "
        "QT_QPA_PLATFORM=offscreen runs it headless."
    )


def missing_from_import_error(message: str) -> list[str]:
    """Sonames an ImportError of PySide6 says it could not open."""
    return list(dict.fromkeys(_CANNOT_OPEN.findall(message)))


def uses_xcb(environ: os._Environ[str] | dict[str, str] | None = None) -> bool:
    """True when Qt will start on its X11 platform (Linux, no other platform chosen)."""
    env = os.environ if environ is None else environ
    if not sys.platform.startswith("linux"):
        return False
    platform = env.get("QT_QPA_PLATFORM", "")
    if platform:
        return platform.split(":")[0] == "xcb"
    wayland = env.get("WAYLAND_DISPLAY") and env.get("XDG_SESSION_TYPE") == "wayland"
    return not wayland
