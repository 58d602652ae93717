"""Why a participant's request is not taken: refusals (they cannot go on, in words for them) and requests that do
not fit their current step. The study's routes turn each into its answer to the page."""

from __future__ import annotations


class Refused(Exception):
    """The participant cannot go on (full, id already used, no id, wrong session); the message says why, in words
    for the participant."""


class Finished(Refused):
    """The participant finished the study, and comes back from a browser without its session: the message thanks
    them and repeats the completion code (``completion_code``, ``redirect_url``: as on the debrief page)."""

    def __init__(self, completion_code: str, redirect_url: str):
        self.completion_code, self.redirect_url = completion_code, redirect_url
        code = f" Your completion code is {completion_code}." if completion_code else ""
        super().__init__(f"You have already completed this study: thank you for taking part.{code}")


class ScreenedOut(Refused):
    """The participant's device or connection cannot take part (``[screening]``): the message says why, and the
    study's return code comes with it."""

    def __init__(self, words: str, return_code: str, redirect_url: str):
        self.return_code, self.redirect_url = return_code, redirect_url
        super().__init__(words)


class Invalid(Exception):
    """The request does not fit the participant's current step; the message names the problem."""


class AnswerProblems(Invalid):
    """Answers that cannot be taken: every problem at once, each ``{question, prompt, problem}`` (its id, its
    text as the participant reads it, what is wrong in words for them); ``again``: a check was answered wrong, and the
    page (its instructions) is shown again."""

    def __init__(self, problems: list[dict], again: bool = False):
        self.problems, self.again = problems, again
        super().__init__("; ".join(f"{p['question']}: {p['problem']}" for p in problems))
