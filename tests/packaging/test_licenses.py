"""The third-party licence file of the frozen build (packaging/licenses.py), from the
distributions installed in this environment."""

import sys

from licenses import bundled_distributions, third_party_text


def test_modules_are_traced_to_their_distributions_and_own_package_left_out():
    dists = bundled_distributions(["numpy.linalg", "scipy", "h5py._hl", "volucal.core", "json"],
                                  exclude=["volucal"])
    assert [d.metadata["Name"].lower() for d in dists] == ["h5py", "numpy", "scipy"]


def test_licence_texts_are_copied_verbatim():
    text = third_party_text(["numpy", "PySide6"])
    # numpy's own LICENSE.txt starts with its copyright line
    assert "Copyright (c) 2005-20" in text and "NumPy Developers" in text
    assert "PySide6_Essentials" in text and "LGPL-3.0-only" in text
    assert f"Python {sys.version.split()[0]}" in text
