"""Stubs of the ``launch`` / ``launch_ros`` packages (not on PyPI) that record what a launch
file builds, shared by the launch files' tests."""
import importlib.util
import sys
import types

#: the launch modules and the classes the package's launch files use
STUBS = {'launch': ['LaunchDescription'],
         'launch.actions': ['DeclareLaunchArgument', 'SetEnvironmentVariable'],
         'launch.conditions': ['IfCondition'],
         'launch.substitutions': ['EnvironmentVariable', 'LaunchConfiguration',
                                  'PathJoinSubstitution'],
         'launch_ros': [], 'launch_ros.actions': ['Node'],
         'launch_ros.substitutions': ['FindPackageShare']}


class Recorded:
    """A stub launch class: keeps its arguments; equal to one made with the same."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs

    def __eq__(self, other):
        same = (self.args, self.kwargs) == (getattr(other, 'args', None),
                                            getattr(other, 'kwargs', None))
        return type(self) is type(other) and same

    def __repr__(self):
        return f'{type(self).__name__}{self.args}{self.kwargs}'


def load_launch(path):
    """The launch file at ``path`` imported as a module."""
    spec = importlib.util.spec_from_file_location(path.name.split('.')[0] + '_launch', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def install_stubs(monkeypatch):
    """Install the stub classes in sys.modules as the launch packages; returns them by name."""
    classes = {}
    for module_name, names in STUBS.items():
        module = types.ModuleType(module_name)
        for name in names:
            classes[name] = module.__dict__[name] = type(name, (Recorded,), {})
        monkeypatch.setitem(sys.modules, module_name, module)
    return classes


def recorded_inside(value):
    """Every Recorded object inside ``value`` (lists, tuples, dicts, stub arguments)."""
    if isinstance(value, Recorded):
        yield value
        for v in (*value.args, *value.kwargs.values()):
            yield from recorded_inside(v)
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from recorded_inside(v)
    elif isinstance(value, dict):
        for v in value.values():
            yield from recorded_inside(v)


def launch_entities(path, stubbed):
    """``(entities, declared, used)`` of the launch file at ``path`` built against the stubs
    ``stubbed`` (:func:`install_stubs`): its LaunchDescription's entities, the arguments it
    declares (name -> default value) and the names of every LaunchConfiguration inside it."""
    description = load_launch(path).generate_launch_description()
    assert isinstance(description, stubbed['LaunchDescription'])
    entities = description.args[0]
    declared = {e.args[0]: e.kwargs['default_value'] for e in entities
                if isinstance(e, stubbed['DeclareLaunchArgument'])}
    used = {c.args[0] for c in recorded_inside(entities)
            if isinstance(c, stubbed['LaunchConfiguration'])}
    return entities, declared, used
