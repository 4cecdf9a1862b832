"""Short questionnaires typed in the window, before and after a study session (thesis 6.1.2, 6.1.4).

The thesis gave its participants a background form before the session (its Appendix A: sex, age,
occupation, computer use, experience of VR simulation and 3-D browsers) and a rating form after it
(Appendix B: understandability, learnability, operability and usefulness of each feature on a scale
of 1 to 10, and suggestions). These are short versions of both, with this trainer's features.

A form is driven by keys like the sign-in form (chainsim.game.trainer.signin): Up/Down (or Tab) move
between questions, Left/Right change a choice or a rating, typing fills a text or number answer
(digits also set a rating), Backspace deletes, Enter moves on and, on the last question, finishes.
Nothing typed here reaches the simulation. `answers()` is what the records store keeps.
"""

from __future__ import annotations

from dataclasses import dataclass

from chainsim.systems.procedures import records_study

#: the study the records hold the trials of
STUDY = records_study()


@dataclass(frozen=True)
class Question:
    id: str
    text: str
    kind: str  # "choice", "rating" (1-10), "number", "text"
    options: tuple[str, ...] = ()


PRE = (
    Question("sex", "Are you", "choice", ("female", "male", "prefer not to say")),
    Question("age", "Your age (years)", "number"),
    Question("occupation", "Your occupation", "text"),
    Question("computer_use", "How often do you use a computer?", "choice", ("never", "sometimes", "very often")),
    Question("vr_simulation", "Have you used a VR-based simulation system?", "choice", ("no", "yes")),
    Question("viewer_3d", "Have you used 3-D viewers or games with a mouse-driven camera?", "choice", ("no", "yes")),
)

#: the post-session ratings of the procedure's features (its study names them; `id`s match the thesis's
#: reported averages where it has one), then suggestions
POST = (
    *(Question(qid, text, "rating") for qid, text in STUDY.ratings),
    Question("improvements", "Suggestions for improving the trainer", "text"),
)

#: post-session averages the thesis reports (6.1.5), on the same 1-10 scale
THESIS_RATINGS = STUDY.published_ratings


class Questionnaire:
    """One form of `questions`; `done` once finished. See the module docstring for the keys."""

    def __init__(self, title: str, intro: str, questions: tuple[Question, ...]):
        self.title = title
        self.intro = intro
        self.questions = questions
        self.values: dict[str, str | int | None] = {q.id: None for q in questions}
        self.focus = 0
        self.done = False

    @property
    def current(self) -> Question:
        return self.questions[self.focus]

    def text(self, typed: str) -> None:
        typed = "".join(ch for ch in typed if ch.isprintable())
        q = self.current
        if not typed:
            return
        if q.kind == "text":
            self.values[q.id] = (str(self.values[q.id] or "") + typed)[:200]
        elif q.kind == "number":
            digits = "".join(ch for ch in typed if ch.isdigit())
            self.values[q.id] = (str(self.values[q.id] or "") + digits)[:3] or None
        elif q.kind == "rating":
            digits = "".join(ch for ch in typed if ch.isdigit())
            if digits:
                # "1" then "0" makes 10; any other digit starts again
                prev = self.values[q.id]
                n = int(digits[-1])
                if prev == 1 and n == 0:
                    self.values[q.id] = 10
                elif 1 <= n <= 9:
                    self.values[q.id] = n
        elif q.kind == "choice":
            for i, opt in enumerate(q.options):
                if opt.lower().startswith(typed.lower()):
                    self.values[q.id] = i
                    break

    def key(self, name: str) -> None:
        q = self.current
        if name in ("down", "tab"):
            self.focus = min(self.focus + 1, len(self.questions) - 1)
        elif name == "up":
            self.focus = max(self.focus - 1, 0)
        elif name in ("left", "right"):
            step = 1 if name == "right" else -1
            if q.kind == "choice":
                cur = self.values[q.id]
                self.values[q.id] = (
                    (0 if step > 0 else len(q.options) - 1) if cur is None else ((int(cur) + step) % len(q.options))
                )
            elif q.kind == "rating":
                cur = self.values[q.id]
                self.values[q.id] = 5 if cur is None else min(max(int(cur) + step, 1), 10)
        elif name == "backspace":
            v = self.values[q.id]
            if q.kind in ("text", "number") and v:
                self.values[q.id] = str(v)[:-1] or None
            elif q.kind in ("rating", "choice"):
                self.values[q.id] = None
        elif name in ("return", "enter"):
            if self.focus == len(self.questions) - 1:
                self.done = True
            else:
                self.focus += 1

    def answers(self) -> dict:
        """Question id -> answer: the option's text, the rating or number as a number, the text; None
        for a question left blank."""
        out: dict = {}
        for q in self.questions:
            v = self.values[q.id]
            if v is None:
                out[q.id] = None
            elif q.kind == "choice":
                out[q.id] = q.options[int(v)]
            elif q.kind in ("rating", "number"):
                out[q.id] = int(v)
            else:
                out[q.id] = str(v)
        return out

    def _shown(self, q: Question) -> str:
        v = self.values[q.id]
        if q.kind == "choice":
            return " / ".join(f"**[{o}]**" if v is not None and i == int(v) else o for i, o in enumerate(q.options))
        if q.kind == "rating":
            return f"**{v}** of 10" if v is not None else "- of 10"
        return f"**{v}**" if v else "-"

    def markdown(self) -> str:
        rows = []
        for i, q in enumerate(self.questions):
            mark = "> " if i == self.focus else ""
            text = f"**{q.text}**" if i == self.focus else q.text
            cursor = " _" if i == self.focus and q.kind in ("text", "number") else ""
            rows.append(f"| {mark}{text} | {self._shown(q)}{cursor} |")
        return (
            "\n".join(
                [
                    f"# {self.title}",
                    "",
                    self.intro,
                    "",
                    "| Question | Answer |",
                    "|---|---|",
                    *rows,
                    "",
                    "**Up / Down** move between questions; **Left / Right** change a choice or a rating (or type "
                    "1-10); type an answer where there is a box; **Enter** goes on, and on the last question finishes.",
                ]
            )
            + "\n"
        )


class Notice:
    """A page that waits for Enter (the next trial's conditions, the summary at the end)."""

    def __init__(self, text: str, enter: str = "Enter"):
        self.body = text
        self.enter = enter
        self.done = False

    def text(self, typed: str) -> None:
        return None

    def key(self, name: str) -> None:
        if name in ("return", "enter"):
            self.done = True

    def markdown(self) -> str:
        return self.body.rstrip() + f"\n\nPress **{self.enter}** to go on.\n"
