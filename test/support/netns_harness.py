"""A harness run whose plant_node lives in another network namespace (a second host).

Run inside the operator station's namespace:

    python -P netns_harness.py SCENARIO OUT_DIR PLANT_NETNS PROGRESS_FIFO

The harness (recorder, gate, controller_node, reference_node) runs here; plant_node is
started through ``ip netns exec PLANT_NETNS``. The environment (``ROS_DOMAIN_ID``, discovery
range, static peers) is passed to every node as it is. Progress goes to PROGRESS_FIFO one line
at a time: ``progress <simulated s>`` while the run goes, then ``done`` or ``failed <reason>``.
The results are the harness's files in OUT_DIR (trace.csv, run.mcap, metrics.json, logs/).
"""
from __future__ import annotations

import sys
from pathlib import Path

from tank_control.harness.runner import Progress, RunFailed, node_module_command, run_scenario
from tank_control.harness.scenario_file import ScenarioError, effective_harness, load_scenario


def main(argv: list[str]) -> int:
    scenario_path, out_dir, plant_netns, fifo = argv
    with open(fifo, 'w', buffering=1) as progress_out:
        def progress(p: Progress) -> None:
            progress_out.write(f'progress {p.sim_time:.9g}\n')

        def command(node: str) -> list[str]:
            argv = node_module_command(node)
            return ['ip', 'netns', 'exec', plant_netns, *argv] if node == 'plant' else argv

        try:
            scenario = effective_harness(load_scenario(scenario_path))
            run_scenario(scenario, Path(out_dir), progress=progress, node_command=command)
        except (RunFailed, ScenarioError) as exc:
            progress_out.write('failed ' + str(exc).replace('\n', ' | ') + '\n')
            return 1
        progress_out.write('done\n')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
