"""What a study that reports in text returns: its lines, kept as the study goes and handed to the
caller's sink as each is made (`dc study` echoes them to stdout), so a long study shows its tables
as they come and no study prints."""
import logging

log = logging.getLogger("deepcontact.studies")


class StudyText:
    """A study's report, line by line: call it as print (text parts, `sep`, `end`); `text()` is
    all of it. `sink(text)`, if given, gets each piece as it is added."""

    def __init__(self, sink=None):
        self.parts, self.sink = [], sink

    def __call__(self, *parts, sep=" ", end="\n", flush=False):
        text = sep.join(map(str, parts)) + end
        self.parts.append(text)
        if self.sink is not None:
            self.sink(text)

    def text(self) -> str:
        return "".join(self.parts)


def progress(message):
    """A study's progress line (training epochs, data made): a log line on stderr, not its report."""
    log.info(message)
