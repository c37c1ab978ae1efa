"""``tank-control list --kinds``: every controller and plant kind with where it comes from
(``built-in``, or the distribution whose entry point adds it; docs/extending.md), its
description, whether it has a linear description for the loop analysis, and the plugins
left out with their one-line reason."""
from __future__ import annotations


def kinds_listing() -> str:
    """The listing as text (one line per kind, then the errors)."""
    from tank_control.core.control.kinds import registry as controllers
    from tank_control.core.plants.kinds import registry as plants
    lines: list[str] = []
    errors: list[str] = []
    for title, table in (('controller kinds', controllers.PLUGINS),
                         ('plant kinds', plants.PLUGINS)):
        lines.append(f'{title}:')
        width = max(len(name) for name in table.kinds)
        origin_width = max(len(origin) for origin in table.origins.values())
        for name, kind in table.kinds.items():
            linear = 'linear' if getattr(kind, 'linear', None) is not None else '-'
            lines.append(f'  {name:<{width}}  {table.origins[name]:<{origin_width}}  '
                         f'{linear:<6}  {kind.description}')
        errors += table.errors
    if errors:
        lines.append('left out:')
        lines += [f'  {error}' for error in errors]
    return '\n'.join(lines) + '\n'
