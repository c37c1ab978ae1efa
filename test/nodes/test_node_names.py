"""Two nodes of one name on one graph (two hand-started ``reference_node``s on a domain) are
reported by both: an ERROR naming the name, the domain and the remedies, once; and when one
goes, the other says it is alone again (nodes/runtime.py ``NameWatch``)."""
from __future__ import annotations

ALONE = '/reference is the only node of its name again'


def test_a_second_node_of_the_same_name_is_reported_and_its_end_too(procs, ros_env, node_cmd,
                                                                    probe):
    for key in ('first', 'second'):
        procs.start(key, node_cmd('reference_node'), env=ros_env)
    first, second = procs.processes['first'], procs.processes['second']
    text = f"2 nodes named /reference on this graph (ROS_DOMAIN_ID {ros_env['ROS_DOMAIN_ID']})"

    def logs() -> str:
        return first.tail(50) + '\n' + second.tail(50)
    assert probe.wait_for(lambda: text in first.tail(50) and text in second.tail(50), 30), logs()
    assert '[ERROR]' in first.tail(50) and '-r __node:=<another name>' in first.tail(50)
    procs.stop('second')
    assert probe.wait_for(lambda: ALONE in first.tail(50), 30), logs()
    assert first.tail(50).count(text) == 1            # logged once, not every 2 s
