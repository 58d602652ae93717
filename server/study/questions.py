"""A study's questions: a questionnaire's items and the comprehension and attention checks (``Question``, a
``[[pages.questions]]`` entry of the study file), what the page's answers may be, and how a check answered wrong is
counted and asked again. See docs/STUDIES.md.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from colorgrid.configkit import check_bool, check_choice, check_int, check_strings, fail
from server.study.errors import AnswerProblems, Invalid

QUESTION_KINDS = ("likert", "choice", "text", "check")
"""``check``: a comprehension or attention check, a choice with one right ``answer`` (``Question.answer``)."""
ID_PATTERN = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
ID_ALLOWED = "1 to 64 letters, digits, '_', '.' or '-'"
READ_AGAIN = {"instructions": "instructions", "questionnaire": "question", "questions": "question"}
"""What a participant is asked to read again after a wrong check, by the kind of page (a step's kind)."""


@dataclass(frozen=True)
class Question:
    """One question of a questionnaire."""

    id: str
    """Its name in the exported ``answers`` table (unique within its questionnaire)."""
    kind: str
    """``likert`` (a scale of ``scale`` points), ``choice`` (one of ``options``) or ``text`` (free text)."""
    prompt: str
    """The question as the participant reads it."""
    required: bool = True
    """Whether the page can be left without an answer."""
    scale: int = 7
    """``likert``: the number of points (answers are 1..scale)."""
    labels: tuple[str, ...] = ()
    """``likert``: the words under the lowest and the highest point (two, or none)."""
    options: tuple[str, ...] = ()
    """``choice`` and ``check``: the options, in the order shown."""
    max_length: int = 2000
    """``text``: the longest answer taken, in characters."""
    answer: str = ""
    """``check``: the right option (one of ``options``; the page never sees it)."""
    tries: int = 2
    """``check``: answers taken before the participant goes on with a wrong one (a failed check, in the export's
    ``exclusions`` table when ``[exclusions] failed_checks`` says so); after each wrong one but the last, the page
    (its instructions, on an instructions page) is shown again."""

    def __post_init__(self):
        if not isinstance(self.id, str) or not ID_PATTERN.match(self.id):
            fail(self, "id", ID_ALLOWED)
        check_choice(self, "kind", QUESTION_KINDS, f"one of {list(QUESTION_KINDS)}")
        if not isinstance(self.prompt, str) or not self.prompt.strip():
            fail(self, "prompt", "the question's text (a non-empty string)")
        check_bool(self, "required")
        check_int(self, "scale", 2, 11, allowed="a whole number in 2..11")
        check_strings(self, "labels")
        if self.kind == "likert" and len(self.labels) not in (0, 2):
            fail(self, "labels", "two words (the lowest and the highest point) or none")
        check_strings(self, "options", distinct=True)
        choosing = self.kind in ("choice", "check")
        if choosing and len(self.options) < 2:
            fail(self, "options", f"at least two distinct options for a {self.kind!r} question")
        if not choosing and self.options:
            fail(self, "options", "only for kind='choice' or kind='check'")
        check_int(self, "max_length", 1, 100_000, allowed="a whole number in 1..100000")
        if not isinstance(self.answer, str) or (self.kind == "check" and self.answer not in self.options):
            fail(self, "answer", f"the right option, one of {list(self.options)}" if self.kind == "check"
                 else "only for kind='check' (the right option)")
        if self.kind != "check" and self.answer:
            fail(self, "answer", "only for kind='check' (the right option)")
        check_int(self, "tries", 1, 10, allowed="a whole number in 1..10")
        if self.kind == "check" and not self.required:
            fail(self, "required", "true for a 'check' question (a check cannot be skipped)")

    def problem(self, value: Any) -> str | None:
        """What is wrong with ``value`` as an answer, in words for the participant (None: it is a valid answer,
        or a skipped optional one)."""
        if value is None or value == "":
            return "Please answer this question." if self.required else None
        if self.kind == "likert":
            ok = isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= self.scale
            return None if ok else f"Choose one of the points from 1 to {self.scale}."
        if self.kind in ("choice", "check"):
            return None if value in self.options else "Choose one of the options."
        if not isinstance(value, str):
            return "Write your answer as text."
        return None if len(value) <= self.max_length else \
            f"Keep your answer to {self.max_length} characters (it has {len(value)})."


def taken_answers(questions: tuple[Question, ...], answers) -> dict:
    """The answers to a page's ``questions`` as they are stored, by question id (an empty answer as None); raises
    ``Invalid`` for answers that are not an object of the page's question ids, and ``AnswerProblems`` with every
    answer that cannot be taken."""
    if not isinstance(answers, dict):
        raise Invalid("answers: an object of question id -> answer")
    unknown = sorted(set(answers) - {q.id for q in questions})
    if unknown:
        raise Invalid(f"answers: unknown question(s) {unknown}")
    problems = [{"question": q.id, "prompt": q.prompt, "problem": q.problem(answers.get(q.id))}
                for q in questions if q.problem(answers.get(q.id))]
    if problems:
        raise AnswerProblems(problems)
    return {q.id: answers.get(q.id) if answers.get(q.id) != "" else None for q in questions}


def count_checks(store, pid: str, step_index: int, step_kind: str, questions: tuple[Question, ...],
                 answers: dict) -> None:
    """Log each check among a page's ``questions`` answered (right or wrong, with its try) in the study's ``store``;
    a wrong one with tries left raises ``AnswerProblems`` with ``again`` (the page, its instructions, is shown again).
    On the last try a wrong answer is kept: the participant goes on, and the export counts a failed check."""
    checks = [q for q in questions if q.kind == "check"]
    if not checks:
        return
    with store.transaction() as tx:
        tried = tx.check_tries(pid, step_index)
        again = []
        for q in checks:
            attempt = tried.get(q.id, 0) + 1
            right = answers[q.id] == q.answer
            tx.log(pid, "check", step=step_index, question=q.id, answer=answers[q.id], right=right, attempt=attempt)
            if not right and attempt < q.tries:
                left = q.tries - attempt
                again.append({"question": q.id, "prompt": q.prompt,
                              "problem": f"That is not right. Please read the {READ_AGAIN[step_kind]} again, "
                                         f"then answer once more ({left} {'try' if left == 1 else 'tries'} "
                                         f"left)."})
    if again:
        raise AnswerProblems(again, again=True)
