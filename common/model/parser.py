"""Text notation for predicates and actions; the inverse of their `str()`."""

from __future__ import annotations

import re
from dataclasses import dataclass

from .actions import Assign
from .predicates import And, Const, Eq, In, IsTrue, Ne, Not, Operand, Or, Predicate, Ref
from .variables import Value

_TOKEN = re.compile(
    r"\s*(?:(?P<op>&&|\|\||==|!=|:=|[!(){},])|(?P<int>-?\d+)|(?P<word>[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z0-9_]+)*))"
)


class ParseError(ValueError):
    """A syntax error in predicate or action text, pointing at the offending column."""

    def __init__(self, text: str, column: int, message: str) -> None:
        self.text, self.column, self.reason = text, column, message
        super().__init__(f"{message} at column {column + 1}:\n  {text}\n  {' ' * column}^")


@dataclass
class _Token:
    kind: str  # "op", "int", "word", "end"
    text: str
    column: int


def _tokenize(text: str) -> list[_Token]:
    tokens: list[_Token] = []
    pos = 0
    while pos < len(text):
        if text[pos:].strip() == "":
            break
        match = _TOKEN.match(text, pos)
        if not match or match.end() == pos:
            column = pos + (len(text[pos:]) - len(text[pos:].lstrip()))
            raise ParseError(text, column, f"unexpected character {text[column]!r}")
        kind = match.lastgroup or "op"
        tokens.append(_Token(kind, match.group(kind), match.start(kind)))
        pos = match.end()
    tokens.append(_Token("end", "", len(text)))
    return tokens


class _Parser:
    def __init__(self, text: str) -> None:
        self.text = text
        self.tokens = _tokenize(text)
        self.pos = 0

    @property
    def peek(self) -> _Token:
        return self.tokens[self.pos]

    def take(self) -> _Token:
        token = self.tokens[self.pos]
        self.pos += 1
        return token

    def expect(self, text: str) -> _Token:
        token = self.take()
        if token.text != text:
            raise ParseError(self.text, token.column, f"expected {text!r}, found {token.text or 'end of text'!r}")
        return token

    def fail(self, message: str) -> ParseError:
        return ParseError(self.text, self.peek.column, message)

    def done(self) -> None:
        if self.peek.kind != "end":
            raise self.fail(f"unexpected {self.peek.text!r}")

    # predicate := or ; or := and ('||' and)* ; and := unary ('&&' unary)*
    def predicate(self) -> Predicate:
        items = [self.conjunction()]
        while self.peek.text == "||":
            self.take()
            items.append(self.conjunction())
        return items[0] if len(items) == 1 else Or(tuple(items))

    def conjunction(self) -> Predicate:
        items = [self.unary()]
        while self.peek.text == "&&":
            self.take()
            items.append(self.unary())
        return items[0] if len(items) == 1 else And(tuple(items))

    def unary(self) -> Predicate:
        if self.peek.text == "!":
            self.take()
            return Not(self.unary())
        return self.atom()

    def atom(self) -> Predicate:
        token = self.peek
        if token.text == "(":
            self.take()
            inner = self.predicate()
            self.expect(")")
            return inner
        if token.kind == "word" and token.text in ("true", "false"):
            self.take()
            return Const(token.text == "true")
        if token.kind != "word" or "." not in token.text:
            raise self.fail(
                f"expected a variable path (resource.name), 'true', 'false', '!' or '(' but found "
                f"{token.text or 'end of text'!r}"
            )
        path = self.take().text
        if self.peek.text in ("==", "!="):
            op = self.take().text
            value = self.operand()
            return Eq(path, value) if op == "==" else Ne(path, value)
        if self.peek.kind == "word" and self.peek.text == "in":
            self.take()
            self.expect("{")
            values: list[Value] = [self.value()]
            while self.peek.text == ",":
                self.take()
                values.append(self.value())
            self.expect("}")
            return In(path, tuple(values))
        return IsTrue(path)

    def operand(self) -> Operand:
        token = self.peek
        if token.kind == "word" and "." in token.text:
            self.take()
            return Ref(token.text)
        return self.value()

    def value(self) -> Value:
        token = self.take()
        if token.kind == "int":
            return int(token.text)
        if token.kind == "word" and "." not in token.text:
            if token.text in ("true", "false"):
                return token.text == "true"
            return token.text
        raise ParseError(self.text, token.column, f"expected a value, found {token.text or 'end of text'!r}")

    def action(self) -> Assign:
        token = self.take()
        if token.kind != "word" or "." not in token.text:
            raise ParseError(self.text, token.column, f"expected a variable path, found {token.text or 'end'!r}")
        self.expect(":=")
        return Assign(token.text, self.operand())


def parse_predicate(text: str) -> Predicate:
    parser = _Parser(text)
    result = parser.predicate()
    parser.done()
    return result


def parse_action(text: str) -> Assign:
    parser = _Parser(text)
    result = parser.action()
    parser.done()
    return result
