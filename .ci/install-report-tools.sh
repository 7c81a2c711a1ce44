#!/usr/bin/env bash
# Installs pdftotext and pdfinfo (Debian poppler-utils) for tests/app/test_report_pdf.py, which
# reads the text and the page count of the rendered calibration report.
# Idempotent: returns at once when the tools are already there.
set -euo pipefail
if command -v pdftotext >/dev/null 2>&1 && command -v pdfinfo >/dev/null 2>&1; then
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  SUDO="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update
$SUDO apt-get install -y --no-install-recommends poppler-utils
