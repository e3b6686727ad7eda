"""``python -m guardrail_core.cli``, as the ``guardrail`` command."""

import sys

from guardrail_core.cli import main

sys.exit(main())
