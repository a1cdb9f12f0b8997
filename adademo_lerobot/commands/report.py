"""adademo-report: markdown report and plots of one or more adademo-run folders."""

import sys

from adademo_lerobot.loop.cli import run_command
from adademo_lerobot.loop.configs import ReportConfig


def main() -> None:
    # `--compare DIR DIR ...` (space separated, as documented) becomes draccus' list syntax.
    argv = sys.argv[1:]
    if "--compare" in argv:
        i = argv.index("--compare")
        dirs = [a for a in argv[i + 1 :] if not a.startswith("--")]
        rest = argv[i + 1 + len(dirs) :]
        sys.argv = [sys.argv[0], *argv[:i], f"--compare=[{','.join(dirs)}]", *rest]
    run_command("adademo_lerobot.loop.report:run_report", ReportConfig)


if __name__ == "__main__":
    main()
