# SPDX-License-Identifier: Apache-2.0
"""Runs unittest modules for ctest: exit 0 when all pass, 1 on a failure or error, 77 (ctest's
SKIP_RETURN_CODE here) when nothing failed but a test skipped itself, so a skip shows as such."""
import sys
import unittest

suite = unittest.defaultTestLoader.loadTestsFromNames(sys.argv[1:])
result = unittest.TextTestRunner(verbosity=2).run(suite)
if not result.wasSuccessful():
    sys.exit(1)
sys.exit(77 if result.skipped else 0)
