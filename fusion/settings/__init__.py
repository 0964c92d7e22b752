"""The localizer's settings groups (pydantic), one module per part they configure.

They import nothing of the project but one another and :mod:`houghloc.config`, so that reading
or checking a configuration loads none of the code it configures: ``import fusion.config`` (the
whole :class:`~fusion.config.LocalizerConfig`) loads no filter, manager or matcher.
"""
