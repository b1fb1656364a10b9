"""`upscale`'s specifications from flat keywords, for tests that list the command's options as a dict."""

from jaxsr.app import ModelChoice, PhotonRules, Reading, Writing


def specs(model="default", **flat):
    """`upscale`'s keyword arguments from the command's options by their flat names (units, bins, preview, ...):
    each sorted into its specification, as the command sorts its flags."""
    fields = {cls: {f for f in cls.__dataclass_fields__} for cls in (ModelChoice, Reading, PhotonRules, Writing)}
    given = {cls: {k: flat.pop(k) for k in list(flat) if k in names} for cls, names in fields.items()}
    out = dict(flat, model=ModelChoice(model, **given[ModelChoice]) if given[ModelChoice] else model)
    for cls, name in ((Reading, "read"), (PhotonRules, "photons"), (Writing, "write")):
        if given[cls]:
            out[name] = cls(**given[cls])
    return out
