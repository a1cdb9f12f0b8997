"""Where adademo keeps its extras inside a standard LeRobot v3.0 dataset (names only; no imports)."""

ADADEMO_DIR = "meta/adademo"
SUITE_FILE = f"{ADADEMO_DIR}/suite.json"
LEDGER_FILE = f"{ADADEMO_DIR}/rounds.jsonl"
TXN_FILE = f"{ADADEMO_DIR}/pending_write.json"
TXN_BACKUP_DIR = f"{ADADEMO_DIR}/pending_write_backup"

# Per-episode columns in meta/episodes.
COL_INITIAL_STATE = "adademo/initial_state"
COL_SEED = "adademo/seed"
COL_ROUND = "adademo/round"
COL_SOURCE = "adademo/source"
COL_COLLECTOR = "adademo/collector"
COL_SUITE = "adademo/suite"
# The whole state an episode starts from (`get_state()`; a robot's joints) and its step: 0 for a demonstration
# from the initial state, the step of the failed rollout where the expert took over for a correction
# (--demo_start=takeover). Episodes that arrived without it have 0 and an empty list.
COL_START_STEP = "adademo/start_step"
COL_START_STATE = "adademo/start_state"
EPISODE_COLUMNS = (
    COL_INITIAL_STATE, COL_SEED, COL_ROUND, COL_SOURCE, COL_COLLECTOR, COL_SUITE, COL_START_STEP, COL_START_STATE,
)  # fmt: skip
# The source of a correction (other episodes: the strategy that added them, `initial`, or IMPORTED_SOURCE).
CORRECTION_SOURCE = "correction"

# Episodes that arrived without adademo columns (recorded elsewhere, or edited by LeRobot's tools, which drop
# extra columns) count as round 0 with this source and no initial state.
IMPORTED_SOURCE = "imported"

# LeRobot's human-in-the-loop datasets (`lerobot-rollout --strategy.type=dagger`): every frame says whether a
# person drove it (`intervention`, bool). Their episodes without adademo columns are read as corrections (a person
# intervened; collector PERSON_COLLECTOR) or as the policy's own (POLICY_SOURCE): `dataset/interventions.py`.
INTERVENTION_FEATURE = "intervention"
POLICY_SOURCE = "policy"
PERSON_COLLECTOR = "teleop"
# Our rounds write POLICY_SOURCE too: the successful rollouts a round keeps (--keep_successes), collector "".


def episode_provenance(source: str, collector: str, is_correction: bool, by_policy: bool) -> tuple[str, str]:
    """An episode's `adademo/source` and `adademo/collector` from its commit's (the round's strategy and
    expert): a correction's source says so, and a kept policy rollout was no expert's."""
    if by_policy:
        return POLICY_SOURCE, ""
    return (CORRECTION_SOURCE if is_correction else source), collector
