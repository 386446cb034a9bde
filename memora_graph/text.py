"""Text utilities every layer shares: word tokens, stemmers and the kitchen vocabulary.

Two tokenizers live here because two parts of the method define theirs:

- `tokenize` / `stem` / `STOPWORDS`: MEMORA-Bench's tokens, used by the metrics
  (PrefAdh, routine matching) and by the readers that score evidence the way the metrics do;
- `index_tokens` / `index_stem` / `INDEX_STOPWORDS`: the retrieval tools' keyword tokens, which agree
  with what Kùzu's full-text index keeps (lower-case words without digits, plurals and -ing/-ed
  folded), so the in-process BM25 and the FTS recipes rank the same words.

`KITCHEN_NOUNS` is the benchmark's fallback object vocabulary.
"""

from __future__ import annotations

import functools
import re

# -- MEMORA-Bench tokens ---------------------------------------------------------------------

STOPWORDS = frozenset(
    "the a an is are was were be to of in on at and or for with by from this that it its person participant "
    "tends typically usually while after before when their they user help".split()
    + [f"p{i:02d}" for i in range(1, 10)]
)
_TOKEN = re.compile(r"\b[a-z][a-z\-]{2,}\b")


def uniq(items) -> list:
    """The items without repeats, in first-seen order."""
    return list(dict.fromkeys(items))


@functools.lru_cache(maxsize=1 << 16)  # the planning metrics stem the same memory words for every item
def stem(word: str) -> str:
    """Strip the first fitting suffix of ing/ied/ies/ed/es/s, then one letter of a final double."""
    for suffix in ("ing", "ied", "ies", "ed", "es", "s"):
        if word.endswith(suffix) and len(word) > len(suffix) + 2:
            word = word[: -len(suffix)]
            break
    if len(word) >= 3 and word[-1] == word[-2]:
        word = word[:-1]
    return word


def tokenize(text: str) -> set[str]:
    return {stem(w) for w in _TOKEN.findall(text.lower()) if w not in STOPWORDS}


def jaccard(a: set[str], b: set[str]) -> float:
    return len(a & b) / len(a | b) if a and b else 0.0


COLOR_WORDS = frozenset(
    "black white red green blue yellow silver grey gray brown pink orange purple gold transparent clear metal metallic".split()
)
KITCHEN_NOUNS = tuple(
    "pot pan wok saucepan kettle bowl plate dish cup mug glass bottle jar can tin container tray board tupperware "
    "box bag basket carton knife spoon fork spatula peeler grater tongs whisk ladle strainer colander opener scoop "
    "microwave toaster blender stove oven hob fridge refrigerator dishwasher sink freezer cooker counter countertop "
    "drawer cabinet cupboard shelf rack table tap faucet burner grill worktop bread toast potato onion garlic carrot "
    "tomato pepper vegetable veg meat chicken rice pasta egg milk cheese butter oil salt sugar flour sauce spice "
    "cereal fruit apple banana lemon herb seasoning bok choy noodle broth cloth sponge towel soap detergent spray "
    "bin trash rubbish tissue paper wipe lid cap handle skin core wrapper peel rind".split()
)
KITCHEN_NOUN_STEMS = frozenset(stem(n) for n in KITCHEN_NOUNS)


# -- retrieval keyword tokens (as Kùzu's FTS indexes text) ------------------------------------------

INDEX_STOPWORDS = frozenset(
    "a an and are as at be by for from has have how i in into is it its me my of on or s that the their them then "
    "there these they this to was were what when where which while who whom why will with you your do does did".split()
)
_WORD = re.compile(r"[a-z]+")


def index_stem(word: str) -> str:
    """A light suffix stemmer (the FTS index uses Porter; this agrees on plurals and -ing/-ed)."""
    for suffix, keep in (("ies", "y"), ("sses", "ss"), ("ing", ""), ("ed", ""), ("es", ""), ("s", "")):
        if word.endswith(suffix) and len(word) - len(suffix) >= 3 and not word.endswith("ss"):
            word = word[: len(word) - len(suffix)] + keep
            break
    if len(word) > 3 and word[-1] == word[-2] and word[-1] not in "lsz":
        word = word[:-1]
    return word


def index_tokens(text: str) -> list[str]:
    """Lower-case words without digits (as Kùzu's FTS indexes them), stopwords dropped, stemmed."""
    return [index_stem(w) for w in _WORD.findall(text.lower()) if w not in INDEX_STOPWORDS]


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """`1 participant`, `2 participants`: a count with its noun in the right number."""
    return f"{n:,} {noun if n == 1 else plural or noun + 's'}"
