"""What the synthetic speakers say: small phrase banks in five languages espeak-ng speaks.

The words matter little to a motion model; sentence length, clause boundaries (where espeak-ng
pauses), questions and exclamations (its intonation) do. A sentence is an optional opener, a
clause, an optional tail clause and a final mark, so each language yields thousands of sentences.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class PhraseBank:
    language: str
    """espeak-ng voice of the language (``en-us``, ``de``, ...): the part before ``+variant``."""
    openers: tuple[str, ...]
    clauses: tuple[str, ...]
    tails: tuple[str, ...]
    backchannels: tuple[str, ...]

    def sentence(self, rng: np.random.Generator) -> str:
        words = []
        if rng.random() < 0.4:
            words.append(str(rng.choice(self.openers)) + ",")
        words.append(str(rng.choice(self.clauses)))
        if rng.random() < 0.45:
            words[-1] += ","
            words.append(str(rng.choice(self.tails)))
        mark = rng.choice([".", ".", ".", "?", "!"])
        text = " ".join(words) + str(mark)
        return text[0].upper() + text[1:]

    def backchannel(self, rng: np.random.Generator) -> str:
        return str(rng.choice(self.backchannels))


_EN = dict(
    openers=("well", "you know", "so", "honestly", "actually", "to be fair", "I mean", "anyway", "right"),
    clauses=(
        "I tried the new route to work this morning",
        "the meeting went on for much longer than anyone expected",
        "we could fix the robot head before the demo on friday",
        "my sister moved to a small town near the coast",
        "the results looked a lot better after the second run",
        "I have been reading a book about old sailing ships",
        "nobody really knew what the plan was",
        "the weather has been strange all week",
        "we should probably write that down somewhere",
        "it took me three hours to find the problem",
        "the kids loved the museum more than I thought they would",
        "I am not sure the numbers add up",
        "they changed the whole menu at the cafe downstairs",
        "the train was late again",
        "I finally cleaned out the garage last weekend",
    ),
    tails=(
        "which surprised me",
        "but that is another story",
        "if you ask me",
        "at least that is what they told me",
        "and then it started raining",
        "so we will see",
        "and nobody complained",
        "but I liked it",
    ),
    backchannels=("mm-hm", "yeah", "right", "okay", "I see", "uh-huh", "oh really", "sure", "yes"),
)

BANKS: dict[str, PhraseBank] = {
    "en-us": PhraseBank("en-us", **_EN),
    "en-gb": PhraseBank("en-gb", **_EN),
    "de": PhraseBank(
        "de",
        openers=("also", "naja", "ehrlich gesagt", "weißt du", "eigentlich", "jedenfalls"),
        clauses=(
            "ich habe heute morgen einen neuen Weg zur Arbeit genommen",
            "das Treffen hat viel länger gedauert als gedacht",
            "wir könnten den Roboter noch vor Freitag reparieren",
            "meine Schwester wohnt jetzt in einer kleinen Stadt am Meer",
            "die Ergebnisse sahen nach dem zweiten Versuch viel besser aus",
            "niemand wusste so richtig, was der Plan war",
            "das Wetter war die ganze Woche seltsam",
            "der Zug hatte schon wieder Verspätung",
            "ich habe drei Stunden nach dem Fehler gesucht",
            "die Kinder fanden das Museum großartig",
        ),
        tails=(
            "was mich überrascht hat",
            "aber das ist eine andere Geschichte",
            "wenn du mich fragst",
            "und dann fing es an zu regnen",
            "mal sehen",
        ),
        backchannels=("mhm", "ja", "genau", "okay", "ach so", "stimmt", "echt"),
    ),
    "fr-fr": PhraseBank(
        "fr-fr",
        openers=("bon", "tu sais", "en fait", "franchement", "alors", "bref"),
        clauses=(
            "j'ai pris un nouveau chemin pour aller au travail ce matin",
            "la réunion a duré beaucoup plus longtemps que prévu",
            "on pourrait réparer le robot avant vendredi",
            "ma sœur habite maintenant dans une petite ville au bord de la mer",
            "les résultats étaient bien meilleurs la deuxième fois",
            "personne ne savait vraiment quel était le plan",
            "il a fait un temps bizarre toute la semaine",
            "le train était encore en retard",
            "j'ai cherché le problème pendant trois heures",
            "les enfants ont adoré le musée",
        ),
        tails=(
            "ce qui m'a surpris",
            "mais c'est une autre histoire",
            "si tu veux mon avis",
            "et puis il a commencé à pleuvoir",
            "on verra bien",
        ),
        backchannels=("mm", "oui", "d'accord", "ah bon", "voilà", "ouais", "je vois"),
    ),
    "es": PhraseBank(
        "es",
        openers=("bueno", "sabes", "la verdad", "en realidad", "pues", "total"),
        clauses=(
            "esta mañana fui al trabajo por un camino nuevo",
            "la reunión duró mucho más de lo que pensábamos",
            "podríamos arreglar el robot antes del viernes",
            "mi hermana vive ahora en un pueblo cerca del mar",
            "los resultados salieron mucho mejor la segunda vez",
            "nadie sabía muy bien cuál era el plan",
            "el tiempo ha estado raro toda la semana",
            "el tren llegó tarde otra vez",
            "estuve tres horas buscando el problema",
            "a los niños les encantó el museo",
        ),
        tails=(
            "lo cual me sorprendió",
            "pero esa es otra historia",
            "si me preguntas",
            "y luego empezó a llover",
            "ya veremos",
        ),
        backchannels=("mm", "sí", "claro", "vale", "ya", "ah", "vaya"),
    ),
    "it": PhraseBank(
        "it",
        openers=("allora", "sai", "in realtà", "sinceramente", "insomma", "comunque"),
        clauses=(
            "stamattina ho preso una strada nuova per andare al lavoro",
            "la riunione è durata molto più del previsto",
            "potremmo riparare il robot prima di venerdì",
            "mia sorella adesso vive in un piccolo paese vicino al mare",
            "i risultati erano molto migliori la seconda volta",
            "nessuno sapeva bene quale fosse il piano",
            "il tempo è stato strano per tutta la settimana",
            "il treno era di nuovo in ritardo",
            "ho cercato il problema per tre ore",
            "ai bambini è piaciuto tantissimo il museo",
        ),
        tails=(
            "il che mi ha sorpreso",
            "ma questa è un'altra storia",
            "se vuoi sapere",
            "e poi ha cominciato a piovere",
            "vedremo",
        ),
        backchannels=("mm", "sì", "certo", "va bene", "ah", "davvero", "esatto"),
    ),
}
"""Phrase banks by espeak-ng language voice."""
