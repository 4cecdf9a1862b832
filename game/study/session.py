"""A study session for a person at the window: questionnaires, counterbalanced trials, Table 6.1 (thesis 6.1.4).

`chainsim protocol PROTOCOL.toml --participant NAME` opens the trainer window and runs one
participant through the protocol, as the thesis ran its volunteers:

1. the pre-session questionnaire (background, chainsim.game.study.questionnaire.PRE), typed in the window;
2. the trials. Each [[trial]] of the protocol is a condition of a task (location: place the three
   points; insertion: aim and insert the needle from points marked for you at their ideal places,
   so every insertion starts the same, as the thesis reset its needle; the needle procedure's study
   declares the tasks, chainsim.systems.procedures.records_study()). The aids are set as the
   condition says and locked for the trial. The conditions of a task are run in cycles, each
   condition once per cycle, `repeat` cycles, and the order within a cycle is counterbalanced between
   participants (rows of a balanced Latin square, by the participant's number in the study), because
   the thesis saw participants improve as they went. The row is the participant's slot in the
   study's register (chainsim.game.study.register): taken from the records server's one sequence
   with `--records`, else from this machine's own register, which the pages say and the trials record
   (``allocation.warning``). `practice = N` in the protocol puts N practice trials before each task's
   scored ones (saved marked ``practice``, never counted). A page before each trial says what comes;
   the trial ends when the participant presses Save attempt;
3. the post-session questionnaire (ratings of each feature, chainsim.game.study.questionnaire.POST);
4. Table 6.1 and the mean ratings over every participant of this study in the records database.

Everything is saved as it happens: the attempts (with `details.protocol`: study, participant, trial,
task, condition, order) and both questionnaires, so a session cut short keeps what was done. With a
records server (``records``) each trial is filed there as well (chainsim.game.records.remote.kept_and_filed). Running
the same participant again resumes after their last saved trial (and skips a questionnaire already
answered), so no trial is made or counted twice; `chainsim protocol --restart` retracts the saved
trials first (kept in the records, marked retracted, never counted) to start over. Attempts retracted
in the records count for nothing here, and of a participant's questionnaires only the newest of each
kind counts.

Ending early is a choice, never an accident: Esc in the window asks first (`end_question`), saying
what is saved and how to continue.

The session is GL-free: the window feeds it keys and text and calls `update()` once per frame; tests
drive it the same way on a headless App. The records server's browser trainer runs it too
(``served``, /train/PACK?study=S: chainsim.game.server.train_session), without questionnaires and
with the trials the server already has in place of the local records.
"""

from __future__ import annotations

import logging

from chainsim.components.hud import HudState
from chainsim.components.resources import Assessment, PackResource, PendingInput, Settings
from chainsim.game.records import remote
from chainsim.game.records.store import RecordStore
from chainsim.game.study import protocol as trials
from chainsim.game.study import register
from chainsim.game.study import table61 as results
from chainsim.game.study.protocol import plan, study_name
from chainsim.game.study.questionnaire import POST, PRE, THESIS_RATINGS, Notice, Questionnaire
from chainsim.game.trainer.headless import attempt_evidence
from chainsim.systems.procedures import records_layout, records_study
from chainsim.systems.view.ui.widgets import WidgetState

#: the attempt as the records keep it (the fixed columns' procedure, chainsim.systems.procedures)
LAYOUT = records_layout()
#: the study the records hold the trials of
STUDY = records_study()

logger = logging.getLogger(__name__)

AIDS = LAYOUT.aids
TASK_DOES = STUDY.task_does
#: a participant's register covariates, recorded with each trial (the validity report's groups read them)
COVARIATES = ("group", "year_of_training", "procedures_performed")
LOCAL_WARNING = register.LOCAL_WARNING


def current_attempts(attempts: list[dict]) -> list[dict]:
    """The attempts that count: not retracted (a restarted participant's earlier trials are)."""
    return [a for a in attempts if not a.get("retracted_at")]


def newest_questionnaires(qs: list[dict]) -> list[dict]:
    """Each participant's newest questionnaire of each kind and session (a restart answers again)."""
    newest: dict[tuple, dict] = {}
    for q in qs:
        key = (q.get("trainee"), q.get("kind"), q.get("session"))
        if key not in newest or (q.get("created_at") or "", q.get("id") or 0) >= (
            newest[key].get("created_at") or "",
            newest[key].get("id") or 0,
        ):
            newest[key] = q
    return list(newest.values())


def saved_trials(attempts: list[dict], study: str, participant: str) -> dict[int, dict]:
    """A participant's saved (not retracted, not scripted) trials of `study`: trial order -> attempt."""
    out = {}
    for a in current_attempts(attempts):
        p = (a.get("details") or {}).get("protocol") or {}
        if p.get("study") == study and p.get("participant") == participant and not p.get("scripted"):
            if isinstance(p.get("order"), int):
                out[p["order"]] = a
    return out


def every_condition(tab: dict, proto: dict) -> dict:
    """Table 6.1 with a column for each condition of the protocol, those without attempts yet too
    (shown as "-" and 0/0), in the protocol's order, so a table says what is still missing."""
    out = {}
    for t in proto["trials"]:
        key = (t["task"], t["condition"])
        out[key] = tab.get(key) or {
            "mean_error_mm": None,
            "scored": 0,
            "attempts": 0,
            "participants": 0,
            "thesis_mm": results.THESIS_MM.get(key),
        }
    return {**out, **{k: v for k, v in tab.items() if k not in out}}


class StudySession:
    """One participant's session on an App (see the module docstring)."""

    def __init__(
        self,
        app,
        proto: dict,
        participant: str,
        class_name: str,
        db,
        side: str = "left",
        restart: bool = False,
        allocation: dict | None = None,
        records: str | None = None,
        served: list[dict] | None = None,
    ):
        self.app = app
        # in the browser trainer: the participant's attempts on the records server, which keeps the trials
        # (no local records, no questionnaires: those are typed at the window); None at the window
        self.served = served
        # the records server the trials are filed on too (each is kept in ``db`` whether or not it answers)
        self.records = records
        # where the participant's order comes from (chainsim.game.study.register.allocate); None: numbered
        # by this machine's records, as before registers, with the warning every trial records
        self.allocation = allocation
        self.restart = restart  # start at the beginning even where a questionnaire was answered before
        self.proto = proto
        self.study = study_name(proto)
        self.participant = participant
        self.class_name = class_name
        self.db = db
        self.side = side
        self.form: Questionnaire | Notice | None = None  # the page shown, if any
        self.state = "new"
        self.trials: list[dict] = []
        self.k = -1
        self.saved_seen = 0
        self.lock_at: float | None = None
        self.done_trials: list[dict] = []
        self.summary = ""
        self.number = 0
        self.post_answered = False

    # -- what the window shows and passes on ------------------------------------------------------
    @property
    def notice(self) -> str:
        return self.form.markdown() if self.form is not None else ""

    @property
    def finished(self) -> bool:
        return self.state == "finished"

    def start(self) -> None:
        if self.records:
            self._file_on(self.records)
        if self.served is not None:
            attempts, qs = current_attempts(self.served), []
        else:
            with RecordStore(self.db) as store:
                attempts = self._attempts(store)
                qs = self._questionnaires(store)
        if self.allocation is None:
            known = []
            for r in results.study_rows(attempts, self.study, practice=True):
                if r["participant"] not in known:
                    known.append(r["participant"])
            number = known.index(self.participant) if self.participant in known else len(known)
            self.allocation = {"by": "this machine", "design": "participants in order of first trial", "slot": number}
            self.allocation["warning"] = LOCAL_WARNING
        self.number = self.allocation["slot"]
        self.trials = plan(self.proto, self.number)
        saved = saved_trials(attempts, self.study, self.participant)
        answered = {q["kind"] for q in qs if q.get("trainee") == self.participant and q.get("session") == self.study}
        if not self.restart and (saved or "pre" in answered):
            self._resume(saved, answered)
            return
        if self.served is not None:  # the browser asks no questions: the first trial's page comes
            self.next_trial()
            return
        self.state = "pre"
        self.form = Questionnaire(
            "Before the session",
            f"Welcome, {self.participant}. A few questions about you first (participant {self.number + 1} "
            f"of study '{self.study}'; {len(self.trials)} trials follow).{self._warning()}",
            PRE,
        )
        self._show()

    def _resume(self, saved: dict[int, dict], answered: set[str]) -> None:
        """Continue after the last saved trial: the trials before it are done, the next one comes."""
        last = max(saved, default=0)
        self.k = min(last, len(self.trials)) - 1
        for order in sorted(saved):
            if order <= len(self.trials):
                t = self.trials[order - 1]
                self.done_trials.append(
                    {"trial": t["name"], "condition": t["condition"], "attempt_id": saved[order]["id"]}
                )
        self.post_answered = "post" in answered
        left = len(self.trials) - last
        if left > 0:
            goes_on = f"The session continues with trial {last + 1} of {len(self.trials)}."
        elif not self.post_answered:
            goes_on = "Every trial is saved; the questions after the session come next."
        else:
            goes_on = "Every trial and both questionnaires are saved; the results over every participant follow."
        self.state = "resume"
        self.form = Notice(
            f"# Welcome back, {self.participant}\n\n"
            f"{len(saved)} of {len(self.trials)} trials of study '{self.study}' are saved"
            f"{' (the last: trial ' + str(last) + ')' if saved else ''}. {goes_on}\n\n"
            + (
                ""
                if self.served is not None
                else "To start over from trial 1 instead, close the window (**Esc**) and run the protocol again "
                "with `--restart`."
            )
        )
        self._show()

    def end_question(self, unsaved: bool = False) -> str | None:
        """What Esc asks before the session ends early (None once the results are shown: nothing is lost)."""
        if self.state in ("summary", "finished"):
            return None
        done = len(self.done_trials)
        lost = ""
        if self.state == "trial" and unsaved:
            lost = f" Trial {self.k + 1} is in progress and **not saved**."
        elif self.state == "trial":
            lost = f" Trial {self.k + 1} is in progress and not saved yet."
        elif self.state in ("pre", "post"):
            lost = " The answers on this page are **not saved** yet."
        nxt = max(self.k, 0) + 1  # the trial shown or in progress (1-based); pre: the first
        again = (
            f"Running `chainsim protocol ... --participant {self.participant}` again continues with trial {nxt}."
            if done < len(self.trials)
            else f"Running `chainsim protocol ... --participant {self.participant}` again continues with the "
            "questions after the session."
        )
        return (
            "# End the session?\n\n"
            f"{done} of {len(self.trials)} trials are saved and stay saved.{lost}\n\n{again}\n\n"
            "Press **Esc** again to end the session, or any other key to go back.\n"
        )

    def text(self, typed: str) -> None:
        if self.form is not None:
            self.form.text(typed)
            self._after_form()

    def key(self, name: str) -> None:
        if self.form is not None:
            self.form.key(name)
            self._after_form()

    def update(self) -> None:
        """Once per frame: lock the trial's aids once they are set; end the trial when it is saved."""
        app = self.app
        if self.state != "trial":
            return
        if self.lock_at is not None and app.time.sim_time >= self.lock_at:
            app.resource(WidgetState).disable(*AIDS)
            self.lock_at = None
        saved = list(app.resource(Assessment).values.get("saved", []))
        if len(saved) > self.saved_seen:
            self.saved_seen = len(saved)
            t = self.trials[self.k]
            self.done_trials.append({"trial": t["name"], "condition": t["condition"], "attempt_id": saved[-1]})
            self.next_trial()

    def _file_on(self, server: str) -> None:
        """Each trial saved in the local records and filed on ``server`` with the same recording."""
        app = self.app
        pack = app.resource(PackResource).pack
        values = app.resource(Settings).values
        kept = {k: values[k] for k in ("class", "trainee", "model") if isinstance(values.get(k), str)}
        evidence = lambda: attempt_evidence(app, pack, kept)  # noqa: E731
        hud = app.resource(HudState)
        app.insert_resource(remote.kept_and_filed(server, self.db, evidence, lambda line: hud.message(line, 8.0)))

    # -- steps ------------------------------------------------------------------------------------
    def _attempts(self, store: RecordStore) -> list[dict]:
        try:
            return current_attempts(store.list_attempts(self.class_name))
        except Exception:  # no such class yet: nobody has taken part
            return []

    def _questionnaires(self, store: RecordStore) -> list[dict]:
        try:
            return newest_questionnaires(store.list_questionnaires(self.class_name))
        except Exception:  # no such class yet
            return []

    def _warning(self) -> str:
        """The allocation's warning as a paragraph of the page (a local order may repeat another machine's)."""
        w = (self.allocation or {}).get("warning")
        return f"\n\n**Warning:** {w}." if w else ""

    def _show(self) -> None:
        self.app.resource(HudState).notice = self.notice

    def _after_form(self) -> None:
        if self.form is None or not self.form.done:
            self._show()
            return
        if self.state == "pre":
            self._save_questionnaire("pre", self._answers())
            self.next_trial()
        elif self.state == "resume":
            self.form = None
            if self.k + 1 >= len(self.trials) and self.post_answered:
                self.finish()
            else:
                self.next_trial()
        elif self.state == "intro":
            self.form = None
            self.begin_trial()
        elif self.state == "post":
            self._save_questionnaire("post", self._answers())
            self.finish()
        elif self.state == "summary":
            self.form = None
            self.state = "finished"
        self._show()

    def _answers(self) -> dict:
        """The answers on the page: in the "pre" and "post" states it is a questionnaire."""
        assert isinstance(self.form, Questionnaire)
        return self.form.answers()

    def _save_questionnaire(self, kind: str, answers: dict) -> None:
        with RecordStore(self.db) as store:
            store.save_questionnaire(self.class_name, self.participant, kind, self.study, answers)

    def next_trial(self) -> None:
        self.k += 1
        if self.k >= len(self.trials) and self.served is not None:
            self.finish()
            return
        if self.k >= len(self.trials):
            self.state = "post"
            self.form = Questionnaire(
                "After the session", "Thank you. Please rate each part of the trainer (1 = poor, 10 = very good).", POST
            )
            self._show()
            return
        t = self.trials[self.k]
        on = [a.replace("_", " ") for a in AIDS if t["aids"].get(a)]
        kind = "Practice trial (not scored)" if t.get("practice") else "Trial"
        # the scene behind the trial's page already shows this trial's aids, not the last trial's
        self.app.resource(WidgetState).enable(*AIDS)
        now = self.app.time.sim_time
        self.app.resource(PendingInput).extend(trials.aid_events(t, now))
        self.state = "intro"
        self.form = Notice(
            f"# {kind} {self.k + 1} of {len(self.trials)}: {results.TASK_TITLE[t['task']]}, "
            f"{t['condition'].replace('_', ' ')}\n\n{TASK_DOES[t['task']]}\n\n"
            f"Aids in this trial: **{', '.join(on) if on else 'none'}** (the others are off and locked)."
            f"{self._warning()}"
        )
        self._show()

    def begin_trial(self) -> None:
        """Set the trial's aids, start a fresh attempt (marked points cleared) and, for an insertion trial,
        mark the ideal points; tag what will be saved with the trial."""
        app = self.app
        t = self.trials[self.k]
        allocation = self.allocation
        assert allocation is not None  # start() made one where none was given
        self.state = "trial"
        ws = app.resource(WidgetState)
        ws.enable(*AIDS)
        now = app.time.sim_time
        pending = app.resource(PendingInput)
        events = trials.session_events(t, now, app.resource(PackResource).pack, self.side)
        pending.extend(events)
        self.lock_at = now + trials.LOCK_AFTER_S  # a replay locks them at the same time (protocol.aid_locks)
        app.resource(Settings).values["protocol"] = {
            "study": self.study,
            "participant": self.participant,
            "participant_number": self.number + 1,
            "trial": t["name"],
            "task": t["task"],
            "condition": t["condition"],
            "order": t["order"],
            "cycle": t["cycle"],
            "practice": bool(t.get("practice")),
            "allocation": {k: v for k, v in allocation.items() if k not in COVARIATES},
            **{k: allocation[k] for k in COVARIATES if k in allocation},
        }
        h = app.resource(HudState)
        h.close_doc()
        h.message(f"Trial {self.k + 1}: {t['condition'].replace('_', ' ')}. Save attempt when you are done.", 8.0)

    def finish(self) -> None:
        """Table 6.1 and the ratings over every participant of the study, shown and kept in `summary`."""
        app = self.app
        app.resource(Settings).values.pop("protocol", None)
        app.resource(WidgetState).enable(*AIDS)
        if self.served is not None:
            self._finish_served()
            return
        with RecordStore(self.db) as store:
            rows = results.study_rows(self._attempts(store), self.study)
            qs = self._questionnaires(store)
        tab = every_condition(results.table([r for r in rows if not r["scripted"]]), self.proto)
        rates = results.ratings(qs, self.study)
        labels = {q.id: q.text for q in POST}
        people = len({r["participant"] for r in rows if not r["scripted"]})
        self.summary = (
            results.format_table(tab, f"{people} participants")
            + "\n\n"
            + results.format_ratings(rates, labels, THESIS_RATINGS)
        )
        self.table = tab
        self.ratings = rates
        self.state = "summary"
        self.form = Notice(
            f"# Study '{self.study}': all participants so far\n\n"
            "Mean error per task and condition over every participant's attempts (thesis Table 6.1: location "
            f"scored by the {STUDY.task_scored['location']}, rotation and insertion by the "
            f"{STUDY.task_scored['insertion']}).\n\n"
            f"{results.markdown_table(tab)}\n\n"
            "Post-session ratings, 1 = poor, 10 = very good:\n\n"
            f"{results.markdown_ratings(rates, labels, THESIS_RATINGS)}\n\n"
            "Thank you for taking part.",
            enter="Enter",
        )
        self._show()

    def _finish_served(self) -> None:
        """The browser trainer's last page: every trial is on the records server (its study report and
        ``chainsim protocol --summary --records`` table them with everyone's)."""
        self.summary = f"{len(self.trials)} trials of study '{self.study}' saved on the records server"
        self.state = "summary"
        self.form = Notice(
            f"# Study '{self.study}': done\n\nAll {len(self.trials)} trials are saved on the records server, "
            "which tables them with every participant's.\n\nThank you for taking part.",
            enter="Enter",
        )
        self._show()
