"""Not an example to follow: variants of lerobot_env_example that each lack one thing a plugin must provide
(docs/lerobot-env.md), for tests/test_plugin_example.py, which expects each refused in one `error:` line.
Registered only with EXAMPLE_PLUGIN_BROKEN_VARIANTS=1, so that they never show among a user's env types."""

import os

if os.environ.get("EXAMPLE_PLUGIN_BROKEN_VARIANTS") == "1":
    from lerobot_env_example_broken import variants  # noqa: F401
