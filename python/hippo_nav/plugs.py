"""Plug points: a registry entry (`Part`) carries its factory, its config model and its config section; a
config section that holds the sections of registered parts (`PartSections`); what a part that keeps state
for a later run offers (`Persistent`).

A registry is a plain `dict[str, Part]` kept by the package of its plug point (`vo.ODOMETRIES`,
`view_cells.DESCRIPTORS`, `closure.PROPOSERS`, like `datasets.LOADERS`). Adding an implementation is its
module and one line in that dict: its settings appear in the config under `Part.section` with the model's
defaults (`hippo-nav run`'s `config.json` lists them), a config file may set them, and a bad value is refused
with the setting's path, exactly as for a built-in part.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Generic, Protocol, TypeVar, get_args, runtime_checkable

import numpy as np
from pydantic import ConfigDict, ModelWrapValidatorHandler, ValidationError, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError
from pydantic_core import ValidationError as CoreValidationError
from pydantic_core.core_schema import ErrorType

from hippo_nav._defaults import ConfigSection

if TYPE_CHECKING:
    from typing_extensions import Self

F_co = TypeVar("F_co", bound=Callable[..., object], covariant=True)
S = TypeVar("S", bound=ConfigSection)

__all__ = ["Part", "PartSections", "Persistent"]


@dataclass(frozen=True)
class Part(Generic[F_co]):
    """One registry entry: `build` makes the part (its signature is the plug point's: it is given its own
    config section first), `config` is that section's model, `section` its name in the config."""

    build: F_co
    config: type[ConfigSection]
    section: str


@runtime_checkable
class Persistent(Protocol):
    """A part whose state can outlive a run (docs/memory.md): `depends_on()` names the settings what it
    stores depends on (a memory made with others is refused), `export_state()` gives its state as named
    arrays, `restore_state(saved)` takes them back into a fresh part."""

    def depends_on(self) -> dict[str, object]: ...

    def export_state(self) -> dict[str, np.ndarray]: ...

    def restore_state(self, saved: dict[str, np.ndarray]) -> None: ...


class PartSections(ConfigSection):
    """A config section that also holds one section per registered part (`part_sections()`, derived from
    registries): each filled with its model's defaults, validated by its model, errors located under its
    name; any other unknown key is still an error. Read one with `section(name)` or as an attribute."""

    model_config = ConfigDict(extra="allow")
    # The registries whose parts' sections this section holds; `part_sections` may derive them otherwise.
    registries: ClassVar[tuple[Callable[[], Mapping[str, Part[Callable[..., object]]]], ...]] = ()

    @classmethod
    def part_sections(cls) -> dict[str, type[ConfigSection]]:
        """Section name → model, for every part of the registries."""
        sections: dict[str, type[ConfigSection]] = {}
        for registry in cls.registries:
            for part in registry().values():
                sections[part.section] = part.config
        return sections

    @model_validator(mode="wrap")
    @classmethod
    def _validate_part_sections(cls, data: object, handler: ModelWrapValidatorHandler[Self]) -> Self:
        if not isinstance(data, dict):
            return handler(data)
        data = dict(data)
        sections = cls.part_sections()
        errors: list[InitErrorDetails] = []
        for name, model in sections.items():
            given = data.get(name, {})
            if isinstance(given, model):
                continue
            try:
                data[name] = model.model_validate(given)
            except ValidationError as err:
                errors.extend(_details(err, name))
        unknown = sorted(set(data) - set(cls.model_fields) - set(sections))
        for key in unknown:
            errors.append(InitErrorDetails(type="extra_forbidden", loc=(key,), input=data[key]))
        if not errors:
            return handler(data)
        # Name every bad setting at once: the other fields' errors too.
        bad = {str(e["loc"][0]) for e in errors}
        try:
            handler({k: v for k, v in data.items() if k not in bad})
        except ValidationError as err:
            errors.extend(_details(err))
        raise CoreValidationError.from_exception_data(cls.__name__, errors)

    def section(self, name: str) -> ConfigSection:
        """The section of the part registered under `name`."""
        extra = self.__pydantic_extra__ or {}
        if name not in extra:
            raise KeyError(f"no config section {name!r}; there are {', '.join(sorted(extra))}")
        value = extra[name]
        if not isinstance(value, ConfigSection):
            raise TypeError(f"config section {name!r} holds a {type(value).__name__}, not a section")
        return value

    def typed_section(self, name: str, model: type[S]) -> S:
        """`section(name)`, checked to be a `model`."""
        value = self.section(name)
        if not isinstance(value, model):
            raise TypeError(f"config section {name!r} is a {type(value).__name__}, not a {model.__name__}")
        return value


_CORE_ERROR_TYPES = frozenset(get_args(ErrorType))
"""The error types pydantic-core can raise again by name; pydantic's own (`path_type` of a `Path` field, …)
are not among them."""


def _details(err: ValidationError, *prefix: str) -> list[InitErrorDetails]:
    """The errors of `err`, located under `prefix`, as they can be raised again. An error type pydantic-core
    does not know by name (Hypothesis found `path_type`: `view_words.vocabulary = []`, which raised a
    KeyError) is raised again as a custom error with the same type and message."""
    details = []
    for e in err.errors():
        if e["type"] in _CORE_ERROR_TYPES:
            detail = InitErrorDetails(type=e["type"], loc=(*prefix, *e["loc"]), input=e["input"])
            if "ctx" in e:
                detail["ctx"] = e["ctx"]
        else:
            # Without a context the rendered message is kept as it is (braces are not placeholders then).
            detail = InitErrorDetails(
                type=PydanticCustomError(e["type"], e["msg"]), loc=(*prefix, *e["loc"]), input=e["input"]
            )
        details.append(detail)
    return details
