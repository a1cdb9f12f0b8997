"""What each command does, one module per command (`collect`, `train`, `evaluate`, `expand`, `record`, `report`,
`push`) and the outer loop that chains them round after round (`run`); `configs` holds the commands' flags and
`cli` parses them (the command line's harness: it sets nothing of the process, so a library user may call it).

Imports run one way: the commands (`adademo_lerobot.commands`) import this layer, which imports the strategies,
never the reverse (`tests/test_structure.py`)."""
